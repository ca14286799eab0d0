"""Paired comparisons (impact_env.eval.paired, used by scripts/agents_report.py and
scripts/paired_comparison.py): policies run on the same drops are compared drop by drop."""

from __future__ import annotations

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


def _run_info(label: str, algo: str, seed: int) -> dict:
    """What scripts/agents_report.run_info reads from a run folder, without the folder."""
    meta = {"algo": algo, "seed": seed, "scene": "rig-randomized", "steps": 1000, "ticks": 4000,
            "wall_time_s": 2.0}
    return {"label": label, "algo": algo, "seed": seed, "meta": meta, "val_best": -1.0, "val_best_step": 500}


def test_agents_report_says_better_from_the_paired_difference(monkeypatch):
    """The report's verdict comes from the paired difference: the agent's energy integral is a
    steady 0.5 ms below pd-penetration's on the same drops (two unpaired intervals would overlap),
    so 'better'; its catch times are drawn like pd-penetration's, so 'NOT shown better'.  The figure
    keys every colour it draws (the shipped agent, other PPO runs, SAC runs, classic laws, the
    oracle) and labels every x axis."""
    import agents_report
    from matplotlib.colors import to_rgba

    base, better = _drops()
    n = base.size
    rng = np.random.default_rng(5)
    labels = ["pd-penetration", "ppo-s0", "ppo-s1", "sac-s0", "oracle"]
    d = {"labels": labels, "specs": labels, "wall_time_s": 1.0,
         "oracle|source": np.array(["cma"] * n), "oracle|cpu_seconds": np.ones(n)}
    energies = {"pd-penetration": base, "ppo-s0": better, "ppo-s1": base + 0.1, "sac-s0": base + 1.0,
                "oracle": base - 5.0}
    for label in labels:
        d[f"{label}|energy_integral_ms"] = energies[label]
        d[f"{label}|time_to_catch_s"] = rng.uniform(0.05, 0.3, n)
        d[f"{label}|bounces"] = np.zeros(n)
        d[f"{label}|rms_force_N"] = np.zeros(n)
        d[f"{label}|failed"] = 0
    args = SimpleNamespace(resamples=2000, boot_seed=7, argv=["--runs", "runs/x"], seed=1000, episodes=n,
                           oracle="oracle", ship="agents/models/best")
    st = agents_report.scene_stats(d, args)
    assert st["_paired"]["ppo-s0"]["energy"].a_better and not st["_paired"]["ppo-s0"]["catch"].a_better
    infos = [_run_info("ppo-s0", "ppo", 0), _run_info("ppo-s1", "ppo", 1), _run_info("sac-s0", "sac", 0)]
    settings = {"results": "docs/results/agents", "command": "--runs runs/x", "seed": 1000, "episodes": n,
                "oracle": "oracle", "resamples": 2000, "boot_seed": 7}
    text = agents_report.report_text(infos, {"rig": st}, "ppo-s0", settings, {"rig": 1.0})
    verdict = next(line for line in text.splitlines() if line.startswith("* ppo-s0 against"))
    catch, energy = verdict.split("; energy integral ")
    assert "paired difference" in catch and catch.rstrip(")").endswith(": NOT shown better")
    assert "paired difference -0.5" in energy and "ms [" in energy
    assert energy.split(")")[1].endswith(": better")  # after '(95 % paired bootstrap over 100 drops)'
    assert "non-overlapping" not in text and "beats it" not in text  # the old, unpaired wording

    from PIL import Image

    seen = {}
    real = agents_report.save_figure

    def keep(fig, path):
        drawn = {to_rgba(c) for a in fig.axes for coll in a.collections for c in coll.get_facecolors()}
        keyed = {to_rgba(h.get_color()) for leg in fig.legends for h in leg.legend_handles}
        seen.update(drawn=drawn, keyed=keyed, xlabels=[a.get_xlabel() for a in fig.axes],
                    key_text=[t.get_text() for leg in fig.legends for t in leg.get_texts()])
        return real(fig, path)

    monkeypatch.setattr(agents_report, "save_figure", keep)
    fig = agents_report.figure({"rig": st}, ROOT / ".pytest_fig.png", "ppo-s0")
    try:
        assert Image.open(fig).info["dpi"][0] >= 149
    finally:
        fig.unlink()
    assert len(seen["drawn"]) == 5 and seen["drawn"] <= seen["keyed"], seen  # every colour drawn has a key
    assert all(x.endswith(("s", "s (right of 0.4: not caught)", "ms (log scale)")) for x in seen["xlabels"])
    assert "SAC runs" in seen["key_text"] and "other PPO runs" in seen["key_text"]
