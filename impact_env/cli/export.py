"""``impact-env export``: any policy spec that compare accepts, as a compiled policy file (and ONNX)."""

from __future__ import annotations

from impact_env.cli.args import add_scene_arguments, scene_from_args
from impact_env.config import ConfigError
from impact_env.deploy.c_export import float32_refusal, generate_c, write_c
from impact_env.deploy.parity import check
from impact_env.policy.export import export_policy, write_onnx


def add_arguments(p) -> None:
    """``export``'s arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    p.add_argument("spec", help="a policy spec as compare takes it: pd-penetration:kp=3e5, ppo:PATH.zip, "
                                "compiled:FILE")
    add_scene_arguments(p, default="rig")
    p.add_argument("--out", metavar="FILE", help="the policy file to write (JSON)")
    p.add_argument("--onnx", metavar="FILE.onnx", help="also write the network as ONNX (MLP policies only)")
    p.add_argument("--c", metavar="DIR", dest="c_dir",
                   help="also write impact_policy.c/.h: the target's whole tick (front end, policy, hold, "
                        "residual, safety) as one dependency-free C99 file (docs/rig/c-export.md)")
    p.add_argument("--force", action="store_true", help="with --c: overwrite the files of an existing DIR")
    p.add_argument("--check", action="store_true",
                   help="with --c: build it with gcc (double and float32) and replay readings recorded "
                        "from the virtual rig through it beside the simulator's kernels; prints PASS or FAIL "
                        "per build against docs/rig/c-export.md's bounds (double: bitwise; float32: 1e-4 "
                        "of full scale where the decisions agree, at most 5 %% of ticks deciding "
                        "differently; a law without a float32 build, e.g. mpc, says so); exit 1 on any FAIL")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from pathlib import Path

    if not (args.out or args.onnx or args.c_dir):
        raise ConfigError("nothing to write: give --out FILE (policy file), --c DIR (C source) and/or "
                          "--onnx FILE")
    if (args.force or args.check) and not args.c_dir:
        raise ConfigError("--force and --check go with --c DIR")
    scene = scene_from_args(args)
    for path in (args.out, args.onnx, args.c_dir):
        if path and not Path(path).resolve().parent.is_dir():
            raise ConfigError(f"cannot write {path!r}: its folder does not exist")
    if args.c_dir and Path(args.c_dir).exists() and not Path(args.c_dir).is_dir():
        # --force overwrites a folder's files; it never replaces a file with a folder
        raise ConfigError(f"--c {args.c_dir}: exists and is not a folder; give a folder for the C files "
                          "(made if absent)")
    if args.c_dir and Path(args.c_dir).exists() and not args.force:
        raise ConfigError(f"--c {args.c_dir}: the folder exists; pass --force to overwrite its files")
    pol = export_policy(args.spec, scene)
    if args.onnx and pol.mlp is None:
        raise ConfigError(f"--onnx: {args.spec!r} is a classic law; only MLP policies are exported to ONNX")
    if args.onnx and pol.estimator is not None:
        raise ConfigError(f"--onnx: {args.spec!r} runs a Kalman filter before its network, which ONNX would "
                          "leave out; use the policy file (--out) or the C export (--c)")
    mlp: dict = pol.mlp or {}
    what = f"law {pol.law['name']}" if pol.law is not None else \
        f"MLP {' x '.join(str(len(ly['bias'])) for ly in mlp['layers'])} ({mlp['output']})"
    names = ", ".join(pol.layout.names)
    if args.c_dir:
        generate_c(pol, scene, spec=args.spec)  # refuses what C cannot express before writing anything
    if args.out:
        pol.save(args.out)
        print(f"{args.out}: {what}, observation {pol.observation} (history {pol.history}: {names}), "
              f"command scale {pol.command_scale:g} N, sha256 {pol.sha256()[:16]}")
    if args.onnx:
        write_onnx(pol, args.onnx)
        print(f"{args.onnx}: ONNX, input obs float32[N, {pol.layout.size}], output action float32[N, 1], "
              "with the observation's meaning in its metadata")
    if args.c_dir:
        h, c = write_c(pol, scene, args.c_dir, force=args.force, spec=args.spec)
        print(f"{c}, {h}: C99, {what}; impact_step(state, readings[4], &command, &force_n) once per tick "
              f"at {pol.control_rate:g} Hz")
        if args.check:
            failed = []
            no_f32 = float32_refusal(pol)
            for f32 in (False, True):
                build = "float32" if f32 else "double"
                if f32 and no_f32:
                    print(f"  check float32 build: none ({no_f32})")
                    continue
                for seed, rep in zip((0, 1), check(pol, scene, args.c_dir, float32=f32), strict=True):
                    passed, line = rep.verdict(f32)
                    print(f"  check {build:7s} build, drop seed {seed}, {rep.ticks} ticks: {line}")
                    if not passed:
                        failed.append(f"{build} (seed {seed})")
            if failed:
                print(f"  FAIL: {', '.join(failed)} outside the bounds docs/rig/c-export.md states "
                      "('How it is checked')", flush=True)
                return 1
            print(f"  PASS: {'the double build' if no_f32 else 'both builds'} within the bounds "
                  "docs/rig/c-export.md states ('How it is checked')")
    return 0
