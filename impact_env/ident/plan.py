"""The identification plan: which episodes ``impact-env rig identify`` runs on a target, and why.

Each episode is armed like a drop (onboard: the target plays it in its tick, through its safety
layer) and logged to HDF5 with its kind and excitation; the fit then needs no other input.

======================  ======  ============================================================
episode                 count   what it exposes
======================  ======  ============================================================
quiet, 1 s              2       the sensors' offsets and noise (first and last: a drift shows)
shaker: log sweep       1       5-200 Hz at 4 N: the suspension's resonance (about 16 Hz) and
                                the band's low edge; 4 N keeps body 2 within a few mm at the
                                resonance, inside the travel limit
shaker: log sweep       1       100-4000 Hz at 40 N: the coil pole and the band's high edge,
                                the force transducer's top mass (large accelerations)
shaker: multisine       1       10-3000 Hz at 30 N: the same band at once, another signal (a
                                check on the model's linearity)
identification drop     5       the pad (c, restitution), m1 and m2 from the contact force and
                                the bounce timing; five to average the drops' scatter
======================  ======  ============================================================

Body 1 stays on the electromagnet in the quiet and shaker episodes (never released); the drops
release the identification body from the scene's drop height with the shaker at 0 N (policy
``passive``).  ``quick`` is a shorter plan (for tests and a first look): the same kinds, shorter.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from impact_env.control.policy import CompiledPolicy
from impact_env.rig import protocol
from impact_env.rig.excitation import Excitation
from impact_env.rig.log import write_episode


@dataclass(frozen=True)
class PlanEpisode:
    kind: str  # quiet | shaker | ident_drop
    duration_s: float
    why: str
    excitation: Excitation | None = None


def default_plan(quick: bool = False, drops: int | None = None) -> list[PlanEpisode]:
    """The plan of the module doc (``quick``: shorter episodes, 3 drops)."""
    q = 0.3 if quick else 1.0
    quiet = PlanEpisode("quiet", q, "the sensors' offsets and noise")
    sweeps = [
        PlanEpisode("shaker", 1.0 if quick else 2.0, "the suspension's resonance and the band's low edge",
                    Excitation("sweep", 4.0, 5.0, 200.0, 0.02)),
        PlanEpisode("shaker", 0.5 if quick else 1.0, "the coil pole, the band's high edge, the top mass",
                    Excitation("sweep", 40.0, 100.0, 4000.0, 0.005)),
    ]
    if not quick:
        sweeps.append(PlanEpisode("shaker", 1.0, "the whole band at once (a linearity check)",
                                  Excitation("multisine", 30.0, 10.0, 3000.0, 0.01)))
    n_drops = drops if drops is not None else (3 if quick else 5)
    drop = PlanEpisode("ident_drop", 0.3 if quick else 0.4,
                       "the pad, m1 and m2: contact force and bounce timing")
    return [quiet, *sweeps, *([drop] * n_drops), quiet]


def run_plan(client, out_dir, plan: list[PlanEpisode] | None = None, seed: int = 0,
             progress: bool = True) -> list[Path]:
    """Run ``plan`` on the target of ``client`` (:class:`impact_env.rig.host.RigClient`), each
    episode's log fetched and written to ``out_dir``; returns the files."""

    plan = default_plan() if plan is None else plan
    scene = client.scene
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    passive = CompiledPolicy.from_law("passive", {}, {}, scene, "sensors")
    files = []
    for j, ep in enumerate(plan):
        n = max(1, int(round(ep.duration_s * scene.control_rate)))
        kind = {"quiet": protocol.EpisodeKind.QUIET, "shaker": protocol.EpisodeKind.SHAKER,
                "ident_drop": protocol.EpisodeKind.IDENT_DROP}[ep.kind]
        t0 = time.perf_counter()
        client.arm("onboard", seed + j, n, kind=kind, excitation=ep.excitation,
                   policy=passive if ep.kind == "ident_drop" else None)
        end = client.wait_end(timeout_s=30.0 + 20.0 * ep.duration_s)
        log = client.fetch_log(end.episode, end.data_sha256)
        files.append(write_episode(log, out, name=f"ident_{j:02d}_{ep.kind}.h5"))
        if progress:
            what = ep.excitation.describe() if ep.excitation is not None else ep.kind
            print(f"identify: episode {j + 1}/{len(plan)} {ep.kind} ({what}, {ep.duration_s:g} s): "
                  f"{protocol.EndReason(end.reason).name} in {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr)
    return files
