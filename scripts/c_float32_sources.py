"""Where a policy's float32 C build departs from the double target: the whole float32 build, then
the same build with only the policy's MLP in double (its weights, sums and activations), each
against the numba double target on the readings of drops ``0 .. N-1`` (the check of
``export --c --check``: the largest command difference, in full scale, on ticks where both builds
take the same discrete decisions, and the first tick past the bound).  When the two rows agree,
the MLP's own float32 arithmetic is not the cause: the observation the float32 front end
computes is, amplified by the network's gain.

A policy with the scene's Kalman filter before its network has no float32 build (the export
refuses it); for one, the rows are the float32 build made anyway (its refusal taken out), the
same with the filter in double (its functions, constants and memory), with the filter and the
MLP in double (only the front end in float32), and that build with its filter told, each tick,
the command the double build gave instead of its own: the loop from the command back through the
filter's prediction cut, so that the row is the front end's readings through the filter and the
network alone.

With ``--closed-loop N``, also the C export's closed-loop statement on drops ``0 .. N-1``: the
float32 build (for a filter student, the refused one) in closed loop with the virtual rig against
the double build, by compare's metrics, each against the bound a command error of 1e-4 of full
scale implies (:func:`impact_env.deploy.parity.closed_loop_check`).

    python scripts/c_float32_sources.py ppo:agents/models/best/model.zip [--scene rig-randomized] [--drops 10]
    python scripts/c_float32_sources.py ppo:runs/quick/best_model.zip --scene rig --closed-loop 6
"""

from __future__ import annotations

import argparse
import ctypes
import re
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


def filter_in_double(source: str) -> str:
    """The generated C with the filter before the network computed in double: its functions and
    constants, the frame it reads and its memory (the network, the front end and the fallback law
    stay in float32)."""
    a = source.index("/* ---- the filter before the network")
    b = source.index("/* ---- the policy: an MLP actor", a)
    part = re.sub(r"\bimpact_real\b", "double", source[a:b])
    rest = source[b:]
    for old, new in (("static const impact_real EST_K[", "static const double EST_K["),
                     ("static const impact_real EST_SCALES[", "static const double EST_SCALES["),
                     ("static impact_real policy_act(const float *obs, impact_real *mem)",
                      "static impact_real policy_act(const float *obs, double *mem)"),
                     ("impact_real v[IMPACT_FRAME_SIZE], frame[3];",
                      "double v[IMPACT_FRAME_SIZE], frame[3];"),
                     ("impact_real *filter_mem", "double *filter_mem"),
                     ("v[j] = (impact_real)obs[j] * EST_SCALES[j];",
                      "v[j] = (double)obs[j] * EST_SCALES[j];"),
                     ("frame, u * COMMAND_SCALE_N);", "frame, (double)u * COMMAND_SCALE_N);")):
        if old not in rest:
            raise SystemExit(f"the generated C has changed: {old!r} not found; update filter_in_double")
        rest = rest.replace(old, new)
    return source[:a] + part + rest


def header_for_filter_in_double(header: str) -> str:
    """The header without the float32 refusal, the filter's memory in double."""
    return re.sub(r"impact_real law_mem\[(\d+)\];  /\* the filter's", r"double law_mem[\1];  /* the filter's",
                  without_refusal(header))


TOLD = re.compile(r"ekf_tick\(EST_K, filter_mem, frame, (\(double\))?u \* COMMAND_SCALE_N\);")


def told_given_command(source: str) -> str:
    """The generated C with the filter before the network told the command in the global
    ``impact_told_command`` (full scale), set by the caller before each tick, instead of its own."""
    if len(TOLD.findall(source)) != 1:
        raise SystemExit(f"the generated C has changed: {TOLD.pattern!r} not found once; "
                         "update told_given_command")
    a = source.index("/* ---- the policy: an MLP actor")
    source = source[:a] + "double impact_told_command;\n\n" + source[a:]
    return TOLD.sub("ekf_tick(EST_K, filter_mem, frame, impact_told_command * COMMAND_SCALE_N);", source)


def replay_told(cp: parity.CPolicy, rec: parity.Recording) -> parity.Recording:
    """:func:`impact_env.deploy.parity.replay` with the filter told the recording's command on
    each tick (the library built with :func:`told_given_command`)."""
    told = ctypes.c_double.in_dll(cp.lib, "impact_told_command")

    def tell(m: int) -> None:
        told.value = rec.command[m]

    return parity.replay(cp, rec, before_tick=tell)


def check_told_is_own(pol, scene, drops: int) -> None:
    """The double build told the recording's commands is the double build, bit for bit: the
    command the filter is told is the recorded one (no safety stage moved it on these drops)."""
    with tempfile.TemporaryDirectory(prefix="c-told-") as tmp:
        d = Path(tmp)
        write_c(pol, scene, d, force=True)
        path = d / "impact_policy.c"
        path.write_text(told_given_command(path.read_text()))
        cp = parity.CPolicy(parity.build_shared(d, d / "lib.so", False), False)
        for seed in range(drops):
            rec = parity.record(pol, scene, seed, TICKS)
            got = replay_told(cp, rec)
            if not np.array_equal(got.command, rec.command):
                raise SystemExit(f"drop {seed}: the double build told its recorded commands departs from "
                                 "the target: the told command is not the recorded one")


def without_refusal(header: str) -> str:
    return re.sub(r'#ifdef IMPACT_FLOAT32\n#error "[^\n]*"\n#endif\n', "", header)


def worst(pol, scene, c_dir: Path, drops: int, told: bool = False) -> list[tuple[float, int]]:
    """Per drop: the largest command difference where the builds decide alike, and the first such
    tick past the bound (-1: none).  ``told``: the build's filter is told the double target's
    commands (:func:`told_given_command`)."""
    cp = parity.CPolicy(parity.build_shared(c_dir, c_dir / "lib.so", True), True)
    out = []
    for seed in range(drops):
        rec = parity.record(pol, scene, seed, TICKS)
        got = replay_told(cp, rec) if told else parity.replay(cp, rec)
        same = ~parity.decisions_differ(rec, got, pol.hold_ticks)
        diff = np.where(same, np.abs(got.command - rec.command), 0.0)
        past = np.nonzero(diff > parity.F32_BOUND)[0]
        out.append((float(diff.max()), int(past[0]) if past.size else -1))
    return out


def closed_loop_rows(pol, scene, drops: int) -> None:
    """Print the closed-loop statement per drop (module doc)."""
    ticks = int(round(scene.episode.horizon * scene.control_rate))
    with tempfile.TemporaryDirectory(prefix="c-closed-") as tmp:
        builds = []
        for float32 in (False, True):
            d = Path(tmp) / ("c32" if float32 else "c64")
            write_c(pol, scene, d, force=True)
            header = next(d.glob("*.h"))
            header.write_text(without_refusal(header.read_text()))
            builds.append(parity.CPolicy(parity.build_shared(d, d / "lib.so", float32), float32))
        print(f"closed loop with the virtual rig, {ticks} ticks: double -> float32 (bound), per metric")
        for seed in range(drops):
            checked = parity.closed_loop_check(builds[0], builds[1], scene, seed, ticks)
            print(f"drop {seed}: " + "; ".join(
                f"{k} {m.double:.5g} -> {m.float32:.5g} "
                f"(bound {m.bound:.2g}: {'within' if m.within else 'PAST'})"
                for k, m in checked.items()), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("policy", help="a policy spec with an MLP, e.g. ppo:agents/models/best/model.zip")
    ap.add_argument("--scene", default="rig-randomized")
    ap.add_argument("--drops", type=int, default=10)
    ap.add_argument("--closed-loop", type=int, default=0, metavar="N",
                    help="also the closed-loop statement on drops 0..N-1 (module doc)")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    pol = export_policy(args.policy, scene)
    if pol.mlp is None:
        raise SystemExit(f"{args.policy} has no MLP: nothing to compare")
    print(f"{args.policy} on {args.scene}, drops 0..{args.drops - 1}: the largest command difference "
          f"where the builds decide alike, full scale (bound {parity.F32_BOUND:g})")
    if pol.estimator is None:
        rows = (("float32 build", None, None, False),
                ("float32 build, MLP in double", mlp_in_double, None, False))
    else:
        check_told_is_own(pol, scene, args.drops)
        rows = (("float32 build", None, without_refusal, False),
                ("float32 build, filter in double", filter_in_double, header_for_filter_in_double, False),
                ("float32 build, filter and MLP in double", lambda c: mlp_in_double(filter_in_double(c)),
                 header_for_filter_in_double, False),
                ("  the same, filter told double's commands",
                 lambda c: told_given_command(mlp_in_double(filter_in_double(c))),
                 header_for_filter_in_double, True))
    for name, edit, edit_header, told in rows:
        with tempfile.TemporaryDirectory(prefix="c-f32-") as tmp:
            d = Path(tmp)
            write_c(pol, scene, d, force=True)
            for pattern, change in (("*.c", edit), ("*.h", edit_header)):
                if change is not None:
                    path = next(d.glob(pattern))
                    path.write_text(change(path.read_text()))
            w = worst(pol, scene, d, args.drops, told)
        first = [t for _, t in w if t >= 0]
        print(f"{name:40s} max {max(x for x, _ in w):.3g}, first past the bound at tick "
              f"{min(first) if first else 'none'}; per drop " + " ".join(f"{x:.2e}" for x, _ in w))
    if args.closed_loop:
        closed_loop_rows(pol, scene, args.closed_loop)


if __name__ == "__main__":
    main()
