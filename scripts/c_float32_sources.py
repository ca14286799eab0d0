"""Where a policy's float32 C build departs from the double target: the whole float32 build, then
the same build with only the policy's MLP in double (its weights, sums and activations), each
against the numba double target on the readings of drops ``0 .. N-1`` (the check of
``export --c --check``: the largest command difference, in full scale, on ticks where both builds
take the same discrete decisions).  When the two rows agree, the MLP's own float32 arithmetic is
not the cause: the observation the float32 front end computes is, amplified by the network's gain.

    python scripts/c_float32_sources.py ppo:agents/models/best/model.zip [--scene rig-randomized] [--drops 10]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from impact_env.deploy import parity
from impact_env.deploy.c_export import write_c
from impact_env.policy.export import export_policy
from impact_env.scene import load_scene

TICKS = 2500  # 0.25 s of each drop: the contacts and the catch


def mlp_in_double(source: str) -> str:
    """The generated C with the MLP actor's section computed in double."""
    a = source.index("/* ---- the policy: an MLP actor")
    b = source.index("/* ----", a + 10)
    part = source[a:b]
    for old, new in (("impact_real x[", "double x["), ("static const impact_real W", "static const double W"),
                     ("static const impact_real B", "static const double B"), ("impact_real c = ",
                                                                               "double c = "),
                     ("impact_real a = ", "double a = "), ("R_TANH(", "tanh("), ("RL(", "(double)(")):
        part = part.replace(old, new)
    return source[:a] + part + source[b:]


def worst(pol, scene, c_dir: Path, drops: int) -> list[float]:
    cp = parity.CPolicy(parity.build_shared(c_dir, c_dir / "lib.so", True), True)
    out = []
    for seed in range(drops):
        rec = parity.record(pol, scene, seed, TICKS)
        got = parity.replay(cp, rec)
        same = ~parity.decisions_differ(rec, got, pol.hold_ticks)
        out.append(float(np.abs(got.command - rec.command)[same].max()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("policy", help="a policy spec with an MLP, e.g. ppo:agents/models/best/model.zip")
    ap.add_argument("--scene", default="rig-randomized")
    ap.add_argument("--drops", type=int, default=10)
    args = ap.parse_args()
    scene = load_scene(args.scene)
    pol = export_policy(args.policy, scene)
    if pol.mlp is None:
        raise SystemExit(f"{args.policy} has no MLP: nothing to compare")
    print(f"{args.policy} on {args.scene}, drops 0..{args.drops - 1}: the largest command difference "
          f"where the builds decide alike, full scale (bound {parity.F32_BOUND:g})")
    for name, edit in (("float32 build", None), ("float32 build, MLP in double", mlp_in_double)):
        with tempfile.TemporaryDirectory(prefix="c-f32-") as tmp:
            d = Path(tmp)
            write_c(pol, scene, d, force=True)
            if edit is not None:
                src = next(d.glob("*.c"))
                src.write_text(edit(src.read_text()))
            w = worst(pol, scene, d, args.drops)
        print(f"{name:30s} max {max(w):.3g}  per drop " + " ".join(f"{x:.2e}" for x in w))


if __name__ == "__main__":
    main()
