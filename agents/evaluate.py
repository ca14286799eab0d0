"""Evaluate a trained model on held-out drops, next to classic laws, with ``impact-env compare``'s
metrics and table.

    python -m agents.evaluate --model runs/e1/best_model.zip --scene rig --episodes 100 --seed 1000 \\
        [--baselines passive,pd-penetration] [--set initial.pre_contact_time=1.0] [--horizon 0.4] \\
        [--compiled] [--json OUT.json]

A thin front end of :func:`impact_env.eval.compare.compare`: the model joins as the policy spec
``ALGO:PATH.zip``, whose ``model.json`` (or ``PATH.json``) gives its observation, history,
``hold_ticks`` and ``residual`` (:mod:`impact_env.policy.sb3`), so the rows are exactly
``impact-env compare --seed SEED``'s on the same drops.  ``--compiled`` first exports the model
to a compiled policy (:mod:`impact_env.policy.export`, written next to the model as
``PATH.policy.json``) and runs that instead: the same commands to about 1e-6 of the command
scale, in the compiled rollout loop, much faster.  The scene is the one given here (``--scene``,
``--set``); the model's training overrides are printed, not applied.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def model_meta(model_path: Path) -> dict:
    """The ``model.json`` (or ``PATH.json``) written next to a model by ``agents.train``, or {}."""
    for p in (model_path.with_suffix(".json"), model_path.parent / "model.json"):
        if p.is_file():
            return json.loads(p.read_text())
    return {}


def model_spec(model_path, meta: dict | None = None) -> str:
    """The compare spec of a saved model: ``ALGO:PATH.zip`` (ALGO from its ``model.json``)."""
    model_path = Path(model_path)
    meta = model_meta(model_path) if meta is None else meta
    algo = str(meta.get("algo", "")).lower()
    return f"{algo}:{model_path}" if algo else str(model_path)


def export_compiled(model_path, scene, out=None) -> str:
    """Export the model (with its hold and residual) to a compiled policy file; its spec.  An
    asymmetric actor-critic (critic on the true state) is exported as its actor, the sensor
    controller it deploys (:func:`agents.policies.deployable`)."""
    from agents.policies import deployable
    from impact_env.policy.export import export_policy

    model_path = Path(model_path)
    actor = deployable(model_path, model_meta(model_path) or None)
    out = Path(out) if out is not None else model_path.with_suffix(".policy.json")
    export_policy(model_spec(actor, model_meta(model_path)), scene).save(out)
    return f"compiled:{out}"


def evaluate(model_path, scene, baselines=("passive", "pd-penetration"), episodes: int = 50, seed: int = 1000,
             horizon: float | None = None, label: str | None = None, compiled: bool = False,
             workers: int | None = 1) -> tuple[dict, dict]:
    """({row name: PolicyRun with ``summary``}, the model's metadata) for the baselines and the
    model on the same drops (``compare``'s rows; the model's row is named ``label`` if given)."""
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    scene = load_scene(scene)
    meta = model_meta(Path(model_path))
    spec = export_compiled(model_path, scene) if compiled else model_spec(model_path, meta)
    runs = compare(scene, [*baselines, spec], episodes=episodes, seed=seed, horizon=horizon, workers=workers,
                   progress=False)
    if label:
        runs = {(label if k == spec else k): v for k, v in runs.items()}
    return runs, meta


def main(argv: list[str] | None = None) -> int:
    from impact_env.cli import add_scene_arguments, scene_from_args
    from impact_env.config import ConfigError
    from impact_env.eval.compare import format_table, summary_json

    p = argparse.ArgumentParser(prog="python -m agents.evaluate", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="a model.zip written by agents.train")
    add_scene_arguments(p, default="rig")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--seed", type=int, default=1000, help="episode j is seeded seed + j (default 1000)")
    p.add_argument("--horizon", type=float, default=None, help="s (default: the scene's)")
    p.add_argument("--baselines", default="passive,pd-penetration", help="comma-separated named policies")
    p.add_argument("--label", default=None, help="row name of the model (default: its spec)")
    p.add_argument("--compiled", action="store_true", help="export the model and run the compiled policy")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the summaries as JSON")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.seed < 0:
        print("agents.evaluate: --episodes must be >= 1 and --seed >= 0", file=sys.stderr)
        return 2
    if not Path(args.model).is_file():
        print(f"agents.evaluate: --model {args.model!r}: no such file", file=sys.stderr)
        return 2
    try:
        scene = scene_from_args(args)
        base = [s for s in (x.strip() for x in args.baselines.split(",")) if s]
        runs, meta = evaluate(args.model, scene, base, args.episodes, args.seed, args.horizon, args.label,
                              compiled=args.compiled, workers=args.workers)
    except (ValueError, ConfigError) as exc:
        print(f"agents.evaluate: {exc}", file=sys.stderr)
        return 2
    horizon = args.horizon if args.horizon is not None else scene.episode.horizon
    print(f"scene {scene.name} ({', '.join(args.set) or 'no overrides'}), episodes seeded "
          f"{args.seed}..{args.seed + args.episodes - 1}; model hold_ticks {meta.get('hold_ticks', 1)}, "
          f"residual {meta.get('residual')}, trained on {meta.get('scene')} with overrides "
          f"{meta.get('overrides', {})}")
    print(format_table(runs, horizon))
    if args.json:
        Path(args.json).write_text(json.dumps({"scene": scene.name, "overrides": args.set, "seed": args.seed,
                                               "episodes": args.episodes, "horizon_s": horizon,
                                               "model_meta": meta, "policies": summary_json(runs)},
                                              indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
