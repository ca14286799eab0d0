"""The statistics ``compare`` and ``benchmark`` report over per-drop metric arrays.

The primary score is :data:`PRIMARY`, the energy integral (``energy_integral_ms``, lower is
better): the one number a comparison is ranked by.  For every policy (``metrics``: metric name ->
float[N], one value per drop, NaN for a failed drop), :func:`policy_statistics` gives:

* ``<metric>_ci95`` for every metric but the catch time: the 95 % bootstrap interval of its mean
  over drops (so a metric added to :data:`impact_env.sim.metrics.EPISODE_METRICS` gets one
  without a change here); ``caught_fraction_ci95`` and ``time_to_catch_median_s_ci95`` (the
  median with not caught counting as infinitely long) for the catch time;
* ``energy_integral_ms_iqm`` and ``energy_integral_ms_iqm_ci95``: the interquartile mean (the
  mean of the middle half of the drops) and its interval, rliable's robust aggregate;
* against a reference policy on the same drops: ``energy_integral_ms_diff`` (mean over drops of
  the policy's minus the reference's) with ``energy_integral_ms_diff_ci95``, and
  ``prob_improvement`` (the share of drops on which the policy's energy integral is lower than
  the reference's, ties counting half; the reference against itself gives exactly 0.5) with
  ``prob_improvement_ci95``;
* with the per-drop energy integrals of ``passive`` and of the oracle: ``score`` (the
  oracle-normalised score, the D4RL form with the per-drop oracle as the expert and doing
  nothing as the floor: ``100 (passive_i - x_i) / (passive_i - oracle_i)`` per drop, then the
  mean over drops: exactly 0 for passive and 100 for the oracle on the same drops, above 100 for
  a policy that beats the oracle on a drop, below 0 for one worse than doing nothing) with
  ``score_ci95``, and its IQM ``score_iqm`` with ``score_iqm_ci95``.

Intervals: :func:`impact_env.eval.paired.bootstrap` (percentile, 10 000 resamples, fewer
beyond 5000 drops: :func:`~impact_env.eval.paired.resamples_for`; the drops resampled together,
within the drop sets when ``strata`` are given), seeded from the command's seed.  A drop where
the oracle is no better than passive (``passive_i - oracle_i <= 0``: the normalisation is
undefined) has no score (NaN) and is left out of the score's statistics.
"""

from __future__ import annotations

import math

import numpy as np

from impact_env.eval.paired import (
    RESAMPLES,
    bootstrap,
    iqm,
    mean,
    mean_difference,
    median_catch,
    prob_improvement,
    resamples_for,
)

PRIMARY = "energy_integral_ms"  # the primary score, lower is better
PRIMARY_LABEL = "energy integral, ms (lower is better)"
CATCH_TIME = "time_to_catch_s"  # summarised by its median (inf: not caught), not its mean


def normalized_score(values, passive, oracle) -> np.ndarray:
    """float[N]: ``100 (passive - values) / (passive - oracle)`` per drop (0 = passive, 100 =
    the oracle); NaN where the oracle is no better than passive on the drop."""
    values, passive, oracle = (np.asarray(x, dtype=np.float64) for x in (values, passive, oracle))
    span = passive - oracle
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(span > 0.0, 100.0 * ((passive - values) / np.where(span > 0.0, span, 1.0)), np.nan)


def _finite(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.isfinite(x), x, np.nan)


def policy_statistics(metrics: dict, *, seed: int = 0, strata=None, reference: dict | None = None,
                      passive=None, oracle=None, resamples: int = RESAMPLES) -> dict:
    """One policy's statistics (the module doc) from its per-drop ``metrics``; ``reference``:
    the reference policy's metrics on the same drops; ``passive``, ``oracle``: their per-drop
    primary scores (float[N]) on the same drops, for the normalised score."""
    n = len(next(iter(metrics.values()))) if metrics else 0
    kw = {"strata": strata, "seed": seed, "resamples": resamples_for(n, resamples)}
    out: dict = {}
    for key, values in metrics.items():
        if key == CATCH_TIME:
            ttc = np.asarray(values, dtype=np.float64)
            caught = np.where(np.isnan(ttc), np.nan, np.isfinite(ttc).astype(np.float64))
            out["caught_fraction_ci95"] = bootstrap(mean, caught, **kw).pair()
            # failed drops are left out, not counted as uncaught (as compare's median)
            out["time_to_catch_median_s_ci95"] = bootstrap(median_catch, ttc, **kw).pair()
            continue
        out[f"{key}_ci95"] = bootstrap(mean, _finite(values), **kw).pair()
    primary = _finite(metrics[PRIMARY])
    q = bootstrap(iqm, primary, **kw)
    out[f"{PRIMARY}_iqm"], out[f"{PRIMARY}_iqm_ci95"] = q.value, q.pair()
    if reference is not None:
        ref = _finite(reference[PRIMARY])
        d = bootstrap(mean_difference, primary, ref, **kw)
        out[f"{PRIMARY}_diff"], out[f"{PRIMARY}_diff_ci95"] = d.value, d.pair()
        pi = bootstrap(prob_improvement, primary, ref, **kw)
        out["prob_improvement"], out["prob_improvement_ci95"] = pi.value, pi.pair()
    if passive is not None and oracle is not None:
        score = normalized_score(primary, passive, oracle)
        s = bootstrap(mean, score, **kw)
        out["score"], out["score_ci95"] = s.value, s.pair()
        s = bootstrap(iqm, score, **kw)
        out["score_iqm"], out["score_iqm_ci95"] = s.value, s.pair()
    return out


def comparison_statistics(metrics: dict[str, dict], *, seed: int = 0, strata=None,
                          reference: str | None = None, passive: str | None = None, oracle: str | None = None,
                          resamples: int = RESAMPLES) -> dict[str, dict]:
    """:func:`policy_statistics` of every policy (name -> per-drop metrics, all on the same
    drops); ``reference``, ``passive``, ``oracle``: the names of those policies among them (or
    None: no paired statistics, no score)."""
    ref = metrics[reference] if reference is not None else None
    floor = metrics[passive][PRIMARY] if passive is not None and oracle is not None else None
    top = metrics[oracle][PRIMARY] if passive is not None and oracle is not None else None
    out = {}
    for name, m in metrics.items():
        out[name] = policy_statistics(m, seed=seed, strata=strata, reference=ref, passive=floor, oracle=top,
                                      resamples=resamples)
        if reference is not None:
            out[name]["reference"] = reference
    return out


def interval_text(value, pair, fmt: str = "{:.2f}") -> str:
    """``"3.34 [3.28, 3.42]"``; ``n/a`` for a missing value, ``inf`` for an infinite one."""
    def f(x):
        if x is None or (isinstance(x, float) and math.isnan(x)):
            return "n/a"
        return ("inf" if x > 0 else "-inf") if math.isinf(x) else fmt.format(x)
    if value is None:
        return "n/a"
    return f"{f(value)} [{f(pair[0])}, {f(pair[1])}]" if pair is not None else f(value)
