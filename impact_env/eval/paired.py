"""Paired comparison of two policies run on the same drops.

``compare`` runs every policy on the same seeded drops, so the right question is not whether two
95 % intervals overlap (a conservative test that ignores the pairing and says nothing about the
size of the difference) but what the per-drop difference is: :func:`paired_difference` bootstraps
a statistic of policy A minus the same statistic of policy B, resampling drops together
(``scipy.stats.bootstrap`` with ``paired=True``), and reports the difference with its interval.
A is better than B (lower is better for an energy integral or a catch time) when the whole
interval lies below 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def median_catch(ttc, axis=-1):
    """compare's median catch time: not caught (inf) counts as infinitely long; failed (NaN) too."""
    x = np.where(np.isnan(ttc), np.inf, ttc)
    return np.median(x, axis=axis)


STATISTICS = {"mean": np.mean, "median_catch": median_catch}


@dataclass(frozen=True)
class PairedDifference:
    """statistic(A) - statistic(B) over the drops, and its bootstrap interval."""

    statistic: str
    difference: float
    low: float
    high: float
    confidence: float
    drops: int

    @property
    def a_better(self) -> bool:
        """The whole interval below 0 (lower is better)."""
        return self.high < 0.0

    @property
    def b_better(self) -> bool:
        return self.low > 0.0

    def text(self, unit: str = "", fmt: str = "{:.3g}") -> str:
        f = (lambda x: "-inf" if x == -math.inf else ("inf" if x == math.inf else fmt.format(x)))
        return (f"{f(self.difference)} {unit} [{f(self.low)}, {f(self.high)}]".replace("  ", " ")
                + f" ({100 * self.confidence:.0f} % paired bootstrap over {self.drops} drops)")


def paired_difference(a, b, statistic: str = "mean", confidence: float = 0.95, resamples: int = 10_000,
                      seed: int = 0) -> PairedDifference:
    """statistic(a) - statistic(b) with a percentile bootstrap interval, the drops resampled
    together (``a[i]`` and ``b[i]`` are the same drop).  ``statistic``: "mean", or
    "median_catch" (catch times, not caught = inf: the difference of compare's medians, which
    may be infinite when a policy does not catch half of a resample)."""
    from scipy import stats

    fn = STATISTICS[statistic]
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1 or a.size < 2:
        raise ValueError(f"a and b must be the same drops (equal 1-d shapes of >= 2), got {a.shape}, "
                         f"{b.shape}")

    def diff(x, y, axis=-1):
        with np.errstate(invalid="ignore"):
            d = fn(x, axis=axis) - fn(y, axis=axis)
        return np.where(np.isnan(d), 0.0, d)  # inf - inf: both uncaught in that resample, no difference

    with np.errstate(invalid="ignore"):  # scipy's spread check on infinite medians
        res = stats.bootstrap((a, b), diff, paired=True, vectorized=True, confidence_level=confidence,
                              n_resamples=resamples, method="percentile",
                              random_state=np.random.default_rng(seed))
    ci = res.confidence_interval
    return PairedDifference(statistic, float(diff(a, b)), float(ci.low), float(ci.high), confidence,
                            int(a.size))
