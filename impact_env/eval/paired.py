"""Paired comparison of two policies run on the same drops.

``compare`` runs every policy on the same seeded drops, so the right question is not whether two
95 % intervals overlap (a conservative test that ignores the pairing and says nothing about the
size of the difference) but what the per-drop difference is: :func:`paired_difference` bootstraps
a statistic of policy A minus the same statistic of policy B, resampling drops together
(``scipy.stats.bootstrap`` with ``paired=True``), and reports the difference with its interval.
A is better than B (lower is better for an energy integral or a catch time) when the whole
interval lies below 0.

The statistics ``compare`` and ``benchmark`` report (:mod:`impact_env.eval.scores`) come from
:func:`bootstrap`: a percentile bootstrap over drops that resamples paired arrays together and,
given ``strata`` (the benchmark's drop sets), resamples within each stratum, as rliable's
stratified bootstrap does (Agarwal et al., "Deep RL at the edge of the statistical precipice",
2021).  Its statistics: :func:`mean`, :func:`iqm` (the interquartile mean, rliable's
``scipy.stats.trim_mean(x, 0.25)``) and :func:`prob_improvement` (the share of drops on which A
beats B, ties counting half: rliable's probability of improvement with every drop a task of one
run).  The generator is ``numpy.random.default_rng([seed, BOOTSTRAP_STREAM])``, fresh for every
interval, so one seed gives one interval, whatever was computed before, and every policy of a
comparison is resampled on the same drops.  rliable itself is not used: it needs ``arch`` (with
``statsmodels``), ``seaborn`` and ``absl-py`` for what is a few lines of numpy here
(docs/benchmark.md, "Statistics").
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
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


# -- the stratified percentile bootstrap (compare's and benchmark's intervals) ------------------------------
BOOTSTRAP_STREAM = 0xB0075  # second word of the bootstrap generator's seed: a stream apart from the drops'
RESAMPLES = 10_000
CONFIDENCE = 0.95
CHUNK_ELEMENTS = 2_000_000  # drops gathered at once (16 MB of float64)
WORK_ELEMENTS = 50_000_000  # resamples x drops of one interval at most: fewer resamples beyond 5000 drops


def resamples_for(n: int, resamples: int = RESAMPLES) -> int:
    """The resamples of an interval over ``n`` drops: ``resamples``, fewer (at least 1000) where
    ``resamples x n`` passes :data:`WORK_ELEMENTS` (a large run's interval is narrow anyway)."""
    return max(min(resamples, 1000), min(resamples, WORK_ELEMENTS // max(n, 1)))


def mean(x, axis=-1):
    return np.mean(x, axis=axis)


def iqm(x, axis=-1):
    """The interquartile mean: the mean of the middle half (25 % trimmed at each end)."""
    from scipy import stats

    return stats.trim_mean(x, 0.25, axis=axis)


def prob_improvement(a, b, axis=-1):
    """The share of drops on which ``a`` is lower (better) than ``b``, ties counting half;
    ``a`` against itself gives exactly 0.5."""
    wins = np.where(a < b, 1.0, np.where(a == b, 0.5, 0.0))
    return np.mean(wins, axis=axis)


def mean_difference(a, b, axis=-1):
    """The paired difference: mean over drops of ``a - b``."""
    return np.mean(a - b, axis=axis)


@dataclass(frozen=True)
class Interval:
    """A statistic over the drops and its percentile bootstrap interval."""

    value: float
    low: float
    high: float

    def pair(self) -> list[float]:
        return [self.low, self.high]


def resample_indices(strata, resamples: int, rng: np.random.Generator) -> np.ndarray:
    """int64[resamples, N]: each row a bootstrap resample of the drops ``0 .. N - 1``, drawn with
    replacement within each stratum (``strata``: int[N], the drop set of each drop), as many from
    a stratum as it holds.  Strata are visited in sorted order, each drawing one block."""
    strata = np.asarray(strata)
    idx = np.empty((resamples, strata.size), dtype=np.int64)
    for s in np.unique(strata):
        members = np.flatnonzero(strata == s)
        idx[:, members] = members[rng.integers(0, members.size, size=(resamples, members.size))]
    return idx


@functools.lru_cache(maxsize=8)
def _indices(strata: tuple, resamples: int, seed: int) -> np.ndarray:
    """:func:`resample_indices` from a fresh generator seeded ``[seed, BOOTSTRAP_STREAM]``, kept:
    every statistic and policy of a comparison resamples the same drops (read-only)."""
    idx = resample_indices(np.asarray(strata), resamples, np.random.default_rng([seed, BOOTSTRAP_STREAM]))
    idx.flags.writeable = False
    return idx


def bootstrap(statistic, *samples, strata=None, confidence: float = CONFIDENCE, resamples: int = RESAMPLES,
              seed: int = 0) -> Interval:
    """``statistic(*samples)`` (each float[N], the same drops) with its percentile bootstrap
    interval at ``confidence``: the drops resampled together, within ``strata`` (int[N]) when
    given.  Drops where a sample is NaN are left out first.  ``seed`` seeds the generator
    (``[seed, BOOTSTRAP_STREAM]``)."""
    arrays = [np.asarray(x, dtype=np.float64) for x in samples]
    n = arrays[0].size
    if any(x.shape != (n,) for x in arrays):
        shapes = [x.shape for x in arrays]
        raise ValueError(f"samples must be the same drops (equal 1-d shapes), got {shapes}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r} must lie in (0, 1)")
    keep = np.all([~np.isnan(x) for x in arrays], axis=0) if n else np.zeros(0, bool)
    arrays = [x[keep] for x in arrays]
    if not keep.any():
        return Interval(math.nan, math.nan, math.nan)
    groups = np.zeros(arrays[0].size, np.int64) if strata is None else np.asarray(strata)[keep]
    rng = np.random.default_rng([int(seed), BOOTSTRAP_STREAM])  # (the generator _indices starts too)
    # resamples in blocks of at most CHUNK_ELEMENTS drops: memory stays bounded for any N
    block = max(1, CHUNK_ELEMENTS // groups.size)
    blocks: Iterable[np.ndarray]
    if block >= resamples:  # one block: the same indices for every interval over these drops
        blocks = [_indices(tuple(groups.tolist()), resamples, int(seed))]
    else:
        blocks = (resample_indices(groups, min(block, resamples - start), rng)
                  for start in range(0, resamples, block))
    values = np.concatenate([statistic(*(x[idx] for x in arrays), axis=-1) for idx in blocks])
    tail = 50.0 * (1.0 - confidence)
    with np.errstate(invalid="ignore"):  # inf - inf between two infinite resamples (a median catch time)
        low, high = np.percentile(values, [tail, 100.0 - tail])
    return Interval(float(statistic(*arrays, axis=-1)), float(low), float(high))
