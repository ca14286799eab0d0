"""Evaluate a model trained with the experimental options (hold, residual) on held-out drops,
next to classic laws, with ``impact-env compare``'s metrics and table.

    python -m agents.evaluate --model runs/e1/model.zip --scene rig --episodes 50 --seed 1000 \\
        [--baselines passive,pd-penetration] [--set initial.pre_contact_time=1.0] [--horizon 0.4] \\
        [--json OUT.json]

``impact-env compare`` runs a saved model as a plain policy at the control rate; a model trained
through :mod:`agents.experimental_wrappers` needs its hold and its residual law around it.  This
reads them from ``model.json`` (``learnability``, ``observation``, ``history``, ``algo``), wraps
the model in :class:`~agents.experimental_wrappers.HeldPolicy` and runs it, and every baseline,
through :func:`impact_env.eval.rollout.rollout` on episodes seeded ``seed + j`` (the drops and
sensor noise ``compare --seed`` gives), so the rows equal ``compare``'s for the baselines and for
a model trained without options (same rollout, same metrics, same summary).  The scene is the one
given here (``--scene``, ``--set``), the same for every row; ``model.json``'s training overrides
are printed, not applied.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def load_held_policy(model_path: Path, scene):
    """The model at ``model_path`` with the options of its ``model.json``, as a tick-level policy."""
    import stable_baselines3 as sb3

    from agents.experimental_wrappers import HeldPolicy, LearnabilityOptions

    meta_path = model_path.with_suffix(".json") if model_path.with_suffix(".json").is_file() \
        else model_path.parent / "model.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    algo = str(meta.get("algo", "ppo")).upper()
    model = getattr(sb3, algo).load(str(model_path), device="cpu")
    options = LearnabilityOptions(**meta.get("learnability", {}))
    policy = HeldPolicy(model, options, scene, observation=meta.get("observation", "sensors"),
                        history=int(meta.get("history", 1)), name=str(model_path))
    return policy, meta


def evaluate(model_path, scene, baselines=("passive", "pd-penetration"), episodes: int = 50, seed: int = 1000,
             horizon: float | None = None, label: str | None = None) -> dict:
    """{row name: PolicyRun with ``summary``} for the baselines and the model, on the same drops."""
    import numpy as np

    from baselines import make_policy
    from impact_env.eval.compare import PolicyRun, summarize
    from impact_env.eval.rollout import rollout
    from impact_env.scene import load_scene

    scene = load_scene(scene)
    seeds = [seed + j for j in range(episodes)]
    horizon = scene.episode.horizon if horizon is None else float(horizon)
    policy, meta = load_held_policy(Path(model_path), scene)
    rows = [(spec, _baseline(spec, scene, make_policy)) for spec in baselines]
    rows.append((label or str(model_path), policy))
    runs = {}
    for name, pol in rows:
        r = rollout(scene, pol, seeds, horizon=horizon, trace_rate=0.0, name=name)
        run = PolicyRun(spec=name, episodes=np.arange(episodes), metrics=r.metrics, failures=r.failures,
                        trace_t=r.trace_t, trace0=None, t_touch0=float(r.t_touch[0]),
                        impact_energy0=float(r.impact_energy[0]), energy_t=None, energy_ratio=None,
                        control_period=r.control_period, wall_time_s=r.wall_time_s)
        run.summary = summarize(run)
        runs[name] = run
    return runs, meta


def _baseline(spec: str, scene, make_policy):
    """A classic law of this project by spec, without the entry-point registry (which loads every
    installed package's policies); other names through the registry."""
    from baselines import POLICIES, parse_spec

    name, params = parse_spec(spec)
    return POLICIES[name](scene, **params) if name in POLICIES else make_policy(spec, scene)


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
    p.add_argument("--label", default=None, help="row name of the model (default: its path)")
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
        runs, meta = evaluate(args.model, scene, base, args.episodes, args.seed, args.horizon, args.label)
    except (ValueError, ConfigError) as exc:
        print(f"agents.evaluate: {exc}", file=sys.stderr)
        return 2
    horizon = args.horizon if args.horizon is not None else scene.episode.horizon
    print(f"scene {scene.name} ({', '.join(args.set) or 'no overrides'}), episodes seeded "
          f"{args.seed}..{args.seed + args.episodes - 1}; model options {meta.get('learnability', {})}, "
          f"trained with overrides {meta.get('overrides', {})}")
    print(format_table(runs, horizon))
    if args.json:
        Path(args.json).write_text(json.dumps({"scene": scene.name, "overrides": args.set, "seed": args.seed,
                                               "episodes": args.episodes, "horizon_s": horizon,
                                               "model_meta": meta, "policies": summary_json(runs)},
                                              indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
