"""The shipped agent against pd-penetration on the same held-out drops, as a paired comparison.

    python scripts/paired_comparison.py [--episodes 100] [--seed 1000] [--workers 2]

Both policies run in ``compare`` on the drops seeded 1000..1099 of ``rig`` and
``rig-randomized`` (the README's held-out drops); for each scene it prints, per drop paired, the
difference agent minus pd-penetration of the mean energy integral (ms) and of compare's median
catch time (s), with 95 % percentile-bootstrap intervals (``scipy.stats.bootstrap``, paired,
10 000 resamples; :mod:`impact_env.eval.paired`).  The agent is better where the whole interval
is below 0.  No training runs and no oracle are needed (``scripts/agents_report.py`` does the
whole report from the run folders).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from impact_env.eval.compare import compare  # noqa: E402
from impact_env.eval.paired import paired_difference  # noqa: E402

AGENT = f"compiled:{ROOT / 'agents/models/best/best.policy.json'}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--scenes", default="rig,rig-randomized")
    args = p.parse_args(argv)
    print("| scene | energy integral, agent - pd-penetration, ms [95 % CI] | median catch, agent - "
          "pd-penetration, s [95 % CI] | agent better on both |")
    print("|---|---|---|---|")
    for scene in args.scenes.split(","):
        runs = compare(scene, [AGENT, "pd-penetration"], episodes=args.episodes, seed=args.seed,
                       workers=args.workers, progress=False)
        ag, pd = runs[AGENT].metrics, runs["pd-penetration"].metrics
        e = paired_difference(ag["energy_integral_ms"], pd["energy_integral_ms"], "mean")
        t = paired_difference(ag["time_to_catch_s"], pd["time_to_catch_s"], "median_catch")
        print(f"| `{scene}` | {e.difference:.2f} [{e.low:.2f}, {e.high:.2f}] | "
              f"{t.difference:.3f} [{t.low:.3f}, {t.high:.3f}] | "
              f"{'yes' if e.a_better and t.a_better else 'no'} |")
    print(f"\n{args.episodes} drops per scene seeded {args.seed}..{args.seed + args.episodes - 1}; paired "
          "percentile bootstrap, 10000 resamples (scipy.stats.bootstrap, paired=True).")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
