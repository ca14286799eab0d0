"""Plots of a comparison in the style of the thesis's figures (matplotlib, imported lazily).

* ``energy.png`` (thesis fig 4.8): body 1's catch energy over time for the first episode of
  every policy (control off = ``passive``), and the median with the interquartile band of the
  energy ratio over all episodes (log scale).
* ``force.png`` (fig 3.2e-f): the force applied to body 2 over time (first episode, first
  30 ms after the touch) and its amplitude spectrum over the episode, with the scene's filter
  band (the force transducer's, when the scene filters) shaded.
* ``motion.png`` (fig 3.2c-d): velocities and displacements of both bodies (first episode),
  upwards positive as in the thesis's plots; one legend below the panels (a colour per policy, a
  line style per body), not eight entries over the curves.
* ``catch_time.png``: the fraction of drops not yet caught against time (a survival curve per
  policy), drops not caught by the end of the episode counted as such (censored).

Time is measured from the first touch, in ms, in every figure (an episode starts
``initial.pre_contact_time``, 1 ms on ``rig``, before it: the simulated drop starts just above the
pad, not at the release).  Each policy keeps one colour in every panel and figure
(:func:`impact_env.eval.labels.policy_colors`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from impact_env.eval.labels import policy_colors
from impact_env.figstyle import save_figure


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


TOUCH_MS = "time from first touch, ms"


def _finish(plt, fig, ax, title: str, path: Path, legend_size: int, xlabel: str | None = None,
            which: str = "major", legend_below: list | None = None) -> Path:
    """Grid, legend and x label on every panel, the title, then write the figure and close it.
    ``legend_below``: these handles in one legend under the panels instead of one per panel."""
    for a in ax:
        if xlabel:
            a.set_xlabel(xlabel)
        a.grid(alpha=0.3, which=which)
        if legend_below is None:
            a.legend(fontsize=legend_size)
    fig.suptitle(title, fontsize=10)
    if legend_below is None:
        fig.tight_layout()
    else:
        fig.legend(handles=legend_below, loc="lower center", ncol=len(legend_below), fontsize=legend_size,
                   frameon=False)
        fig.tight_layout(rect=(0.0, 0.07, 1.0, 1.0))  # room for the legend row
    return save_figure(fig, path)


def _t_ms(run):
    return (run.trace_t - run.t_touch0) * 1e3


def plot_energy(runs, path: Path, scene) -> Path:
    plt = _plt()
    colors = policy_colors(runs)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for spec, run in runs.items():
        if run.trace0 is None:
            continue
        ax[0].plot(_t_ms(run), run.trace0["catch_energy"] * 1e3, lw=1, color=colors[spec], label=spec)
        if run.energy_ratio is not None and run.energy_ratio.size:
            t = (run.energy_t - run.t_touch0) * 1e3
            q25, q50, q75 = np.quantile(run.energy_ratio, [0.25, 0.5, 0.75], axis=1)
            floor = 1e-6
            ax[1].semilogy(t, np.maximum(q50, floor), color=colors[spec], lw=1, label=spec)
            ax[1].fill_between(t, np.maximum(q25, floor), np.maximum(q75, floor), color=colors[spec],
                               alpha=0.2)
    ax[0].set_title("body 1's catch energy, episode 0 (cf. thesis fig 4.8a)", fontsize=9)
    ax[0].set_ylabel("catch energy, mJ")
    n = max((len(r.episodes) for r in runs.values()), default=0)
    ax[1].set_title(f"median and IQR of {n} episodes (dotted: 1 %)", fontsize=9)
    ax[1].set_ylabel("catch energy / impact energy")
    ax[1].axhline(0.01, color="k", lw=0.6, ls=":")
    return _finish(plt, fig, ax, f"scene {scene.name}: energy of the falling body", path, 7, TOUCH_MS)


def force_spectrum(force: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(frequency Hz, amplitude N) of a force record: |rfft| * 2 / n, the amplitude of each
    sinusoidal component (a 1 N sine at a bin frequency reads 1 N).  For energy shares by band
    (Parseval: ``scripts/reproduce_thesis.py``); plots use :func:`force_asd`."""
    n = len(force)
    amp = np.abs(np.fft.rfft(force)) * 2.0 / max(n, 1)
    return np.fft.rfftfreq(n, dt), amp


def force_asd(force: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(frequency Hz, amplitude spectral density N/sqrt(Hz)) of a force record by Welch's method
    (``scipy.signal.welch``: Hann segments of half the record, half overlapping, three averaged:
    steadier than one raw FFT of the whole record, whose bins scatter by their own variance, and
    fine enough for the thesis's 20 Hz band edge on a 0.1 s record)."""
    from scipy import signal

    n = len(force)
    freq, psd = signal.welch(force, fs=1.0 / dt, nperseg=max(min(n, 16), n // 2), scaling="density")
    return freq, np.sqrt(psd)


def filter_band(scene) -> tuple[float, float] | None:
    """(low, high) Hz of the band the scene's filters pass on the force transducer (the
    accelerometer's if the force channel is unfiltered), or None if the scene does not filter."""
    fx = scene.effects
    if not fx.on("filters"):
        return None
    for ch in (fx.filters.force, fx.filters.accelerometer):
        if ch.kind == "bandpass":
            return ch.low_hz, ch.high_hz
        if ch.kind == "lowpass":
            return 0.0, ch.high_hz
    return None


def plot_force(runs, path: Path, scene, window_ms: float = 30.0) -> Path:
    plt = _plt()
    colors = policy_colors(runs)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    silent: list[str] = []
    for spec, run in runs.items():
        if run.trace0 is None:
            continue
        t = _t_ms(run)
        f = run.trace0["force_applied"]
        sel = (t >= -1.0) & (t <= window_ms)
        if not np.any(f != 0):  # a policy that applies no force: said, not drawn as a flat line
            silent.append(spec)
            continue
        ax[0].plot(t[sel], f[sel], lw=1, color=colors[spec], label=spec)
        dt = float(run.trace_t[1] - run.trace_t[0]) if len(run.trace_t) > 1 else run.control_period
        freq, amp = force_asd(f, dt)
        ax[1].loglog(freq[1:], np.maximum(amp[1:], 1e-9), lw=0.8, color=colors[spec], label=spec)
    ax[0].set_title("force on body 2 (up positive), episode 0 (cf. thesis fig 3.2e)", fontsize=9)
    ax[0].set_xlabel("time from first touch, ms")
    ax[0].set_ylabel("force, N")
    band = filter_band(scene)
    if band is not None:
        lo, hi = band
        ax[1].axvspan(max(lo, 1e-3), hi, color="0.85", zorder=0,
                      label=f"scene's sensor filter band, {lo:g}-{hi:g} Hz")
    ax[1].set_title("its amplitude spectral density over the episode (Welch; cf. fig 3.2f)", fontsize=9)
    ax[1].set_xlabel("frequency, Hz")
    ax[1].set_ylabel("amplitude density, N/sqrt(Hz)")
    none = f" (no force: {', '.join(silent)})" if silent else ""
    return _finish(plt, fig, ax, f"scene {scene.name}: shaker force{none}", path, 7, which="both")


def plot_motion(runs, path: Path, scene, window_ms: float = 100.0) -> Path:
    plt = _plt()
    colors = policy_colors(runs)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for spec, run in runs.items():
        if run.trace0 is None:
            continue
        t = _t_ms(run)
        sel = t <= window_ms
        tr = run.trace0
        c = colors[spec]
        ax[0].plot(t[sel], -tr["v1"][sel], lw=1, color=c, label=f"{spec}: body 1")
        ax[0].plot(t[sel], -tr["v2"][sel], lw=1, ls="--", color=c, label=f"{spec}: body 2")
        ax[1].plot(t[sel], -tr["x1"][sel] * 1e3, lw=1, color=c, label=f"{spec}: body 1")
        ax[1].plot(t[sel], -tr["x2"][sel] * 1e3, lw=1, ls="--", color=c, label=f"{spec}: body 2")
    ax[0].set_title("velocities, up positive (cf. thesis fig 3.2c)", fontsize=9)
    ax[0].set_ylabel("velocity, m/s")
    ax[1].set_title("surface positions, up positive (cf. fig 3.2d)", fontsize=9)
    ax[1].set_ylabel("height, mm")
    # 2 lines per policy: a legend entry per policy (its colour) and per body (its line style)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=colors[spec], lw=1.5, label=spec)
               for spec, run in runs.items() if run.trace0 is not None]
    handles += [Line2D([], [], color="0.3", lw=1, label="body 1 (falling)"),
                Line2D([], [], color="0.3", lw=1, ls="--", label="body 2 (shaker)")]
    return _finish(plt, fig, ax, f"scene {scene.name}: motion of the bodies, episode 0", path, 7, TOUCH_MS,
                   legend_below=handles)


def survival_curve(ttc) -> tuple[np.ndarray, np.ndarray]:
    """The fraction of episodes not yet caught against time (a step function: ``frac[k]`` holds
    from ``t[k]`` to ``t[k + 1]``), from the catch times ``ttc`` (s; ``inf`` = not caught within
    the horizon: censored, so the curve ends above 0 by their share; NaN = a failed episode,
    left out).  It crosses 1/2 at the median the table prints (``summarize``'s
    ``time_to_catch_median_s``, which counts the censored episodes as infinitely long)."""
    x = np.asarray(ttc, dtype=float)
    x = np.sort(x[~np.isnan(x)])
    n = x.size
    fin = x[np.isfinite(x)]
    t = np.concatenate([[0.0], fin])
    frac = 1.0 - np.arange(fin.size + 1) / max(n, 1)
    return t, frac


def plot_catch_time(runs, path: Path, scene, horizon: float) -> Path:
    """The catch time as a survival curve per policy: the fraction of drops not yet caught
    against the time from the first touch (ms, as the other figures; the table's catch times
    are from the touch too).  Drops not caught by the end of the episode are censored: the curve
    ends at their share there (the horizon less the time before the touch), instead of leaving
    them out (a box over the caught drops alone put pd-penetration's median at 0.18 s where the
    table, counting them, says 0.388 s).  The median of the table is where a curve crosses 1/2,
    marked with a dot."""
    plt = _plt()
    colors = policy_colors(runs)
    fig, ax = plt.subplots(figsize=(7.5, 4.4))
    ends = []
    for spec, run in runs.items():
        ttc = np.asarray(run.metrics["time_to_catch_s"], dtype=float)
        t, frac = survival_curve(ttc)
        if t.size == 1 and np.isnan(ttc).all():
            continue
        t_touch = getattr(run, "t_touch0", math.nan)  # s after the episode start
        end = horizon - t_touch if math.isfinite(t_touch) and 0.0 <= t_touch < horizon else horizon
        ends.append(end)
        ts = np.append(t, end) * 1e3
        fs = np.append(frac, frac[-1])
        med = run.summary.get("time_to_catch_median_s", math.nan) if run.summary else math.nan
        lab = (f"{spec}: median {med * 1e3:.0f} ms" if math.isfinite(med)
               else f"{spec}: median > {end * 1e3:.0f} ms")
        ax.step(ts, fs, where="post", color=colors[spec], lw=1.6, label=lab)
        if math.isfinite(med):
            ax.plot([med * 1e3], [0.5], "o", color=colors[spec], ms=5, zorder=3)
        if frac[-1] > 0:
            ax.plot([end * 1e3], [frac[-1]], ">", color=colors[spec], ms=6, zorder=3)
    end_ms = (max(ends) if ends else horizon) * 1e3
    ax.axhline(0.5, color="k", lw=0.6, ls=":")
    ax.set_xlim(0.0, end_ms * 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(TOUCH_MS)
    ax.set_ylabel("fraction of drops not yet caught")
    ax.grid(alpha=0.3)
    # the curves start at 1 and fall late: the lower left is where no curve runs
    ax.legend(fontsize=7, loc="lower left", framealpha=0.9)
    n = max((len(r.episodes) for r in runs.values()), default=0)
    ax.set_title(f"scene {scene.name}: catch time, {n} drops per policy (caught: catch energy below 1 % for "
                 f"good)\ndots: the median; triangles at the episode's end ({end_ms:.0f} ms after the "
                 "touch): the share never caught", fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
