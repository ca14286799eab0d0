"""The benchmark's plot: performance profiles (rliable's form) with stratified bootstrap bands."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from impact_env.figstyle import save_figure

THRESHOLDS = np.linspace(-25.0, 125.0, 151)  # score thresholds (0 = passive, 100 = the oracle)
PROFILE_RESAMPLES = 2000


def profile(scores: np.ndarray, thresholds=THRESHOLDS) -> np.ndarray:
    """float[T]: the share of drops whose score exceeds each threshold (NaN scores left out)."""
    s = scores[~np.isnan(scores)]
    if not s.size:
        return np.full(len(thresholds), np.nan)
    return (s[:, None] > np.asarray(thresholds)[None, :]).mean(axis=0)


def profile_band(scores: np.ndarray, strata: np.ndarray, seed: int, thresholds=THRESHOLDS,
                 confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Pointwise percentile bands of :func:`profile` over stratified bootstrap resamples."""
    from impact_env.eval.paired import BOOTSTRAP_STREAM, resample_indices

    keep = ~np.isnan(scores)
    s, g = scores[keep], strata[keep]
    rng = np.random.default_rng([int(seed), BOOTSTRAP_STREAM])
    idx = resample_indices(g, PROFILE_RESAMPLES, rng)
    curves = (s[idx][:, :, None] > np.asarray(thresholds)[None, None, :]).mean(axis=1)
    tail = 50.0 * (1.0 - confidence)
    low, high = np.percentile(curves, [tail, 100.0 - tail], axis=0)
    return low, high


def plot_profiles(record: dict, scores: dict[str, tuple[np.ndarray, np.ndarray]], path: Path) -> Path:
    """Every policy's performance profile over the suite's drops: ``scores`` maps each policy,
    best first, to its oracle-normalised score per drop and the drop's set (the strata)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seed = record["suite"]["sets"][0]["seed"]
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for spec, (per_drop, strata) in scores.items():
        if not np.any(~np.isnan(per_drop)):
            continue
        line, = ax.plot(THRESHOLDS, profile(per_drop), label=_label(spec))
        low, high = profile_band(per_drop, strata, seed)
        ax.fill_between(THRESHOLDS, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
    ax.set_xlabel("score threshold tau (0 = passive, 100 = per-drop oracle)")
    ax.set_ylabel("share of drops with score > tau")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    suite = record["suite"]
    drops = sum(s["drops"] for s in record["sets"].values())
    ax.set_title(f"{suite['name']}: performance profiles over {drops} drops "
                 "(95 % stratified bootstrap bands)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def _label(spec: str) -> str:
    if spec.startswith("compiled:"):
        return Path(spec.partition(":")[2]).parent.name + " (compiled)"
    return spec
