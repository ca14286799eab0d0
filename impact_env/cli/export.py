"""``impact-env export``: any policy spec that compare accepts, as a compiled policy file (and ONNX)."""

from __future__ import annotations

from impact_env.cli.args import scene_from_args


def add_parser(sub, scene_args) -> None:
    p = sub.add_parser("export", help="write a policy as a compiled policy file (runs without Python; "
                                      "optionally also ONNX)")
    p.add_argument("spec", help="a policy spec as compare takes it: pd-penetration:kp=3e5, ppo:PATH.zip, "
                                "compiled:FILE")
    scene_args(p)
    p.add_argument("--out", required=True, metavar="FILE", help="the policy file to write (JSON)")
    p.add_argument("--onnx", metavar="FILE.onnx", help="also write the network as ONNX (MLP policies only)")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from pathlib import Path

    from impact_env.config import ConfigError
    from impact_env.policy.export import export_policy, write_onnx

    scene = scene_from_args(args)
    for path in (args.out, args.onnx):
        if path and not Path(path).resolve().parent.is_dir():
            raise ConfigError(f"cannot write {path!r}: its folder does not exist")
    pol = export_policy(args.spec, scene)
    if args.onnx and pol.mlp is None:
        raise ConfigError(f"--onnx: {args.spec!r} is a classic law; only MLP policies are exported to ONNX")
    pol.save(args.out)
    what = f"law {pol.law['name']}" if pol.law is not None else \
        f"MLP {' x '.join(str(len(ly['bias'])) for ly in pol.mlp['layers'])} ({pol.mlp['output']})"
    names = ", ".join(pol.layout.names)
    print(f"{args.out}: {what}, observation {pol.observation} (history {pol.history}: {names}), "
          f"command scale {pol.command_scale:g} N, sha256 {pol.sha256()[:16]}")
    if args.onnx:
        write_onnx(pol, args.onnx)
        print(f"{args.onnx}: ONNX, input obs float32[N, {pol.layout.size}], output action float32[N, 1]")
    return 0
