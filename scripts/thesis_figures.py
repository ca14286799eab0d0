"""Figures of ``scripts/reproduce_thesis.py``: our versions of the thesis's figures 3.1, 3.2a-f,
4.6, 4.7 and 4.8 from :class:`impact_env.eval.compare.PolicyRun` results (fig 4.4 is drawn by
:func:`impact_env.eval.sweep.plot`).  Time is from the first touch; heights and velocities are drawn
upwards positive, as in the thesis.  Each written by :func:`impact_env.figstyle.save_figure` (150 dpi;
the file's suffix picks png, pdf or svg)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from impact_env.eval.compare_plots import force_asd, force_spectrum  # noqa: E402, F401
from impact_env.figstyle import save_figure  # noqa: E402
from impact_env.plant.energy import catch_energy, energies, energy_above_rest  # noqa: E402


def t_ms(run):
    return (run.trace_t - run.t_touch0) * 1e3


def body_energies(run, scene) -> dict:
    """Energies of the first episode (J): kinetic1, kinetic2, elastic, suspension, gravity, total
    (:func:`impact_env.plant.energy.energies`), catch (body 1 relative to resting on body 2) and
    above_rest (the whole system's energy above its rest,
    :func:`~impact_env.plant.energy.energy_above_rest`)."""
    p, tr = scene.plant, run.trace0
    e = energies(tr["x1"], tr["v1"], tr["x2"], tr["v2"], p.m1, p.m2, p.c, p.gravity, p.suspension_stiffness)
    e["catch"] = catch_energy(tr["x1"], tr["v1"], tr["x2"], p.m1, p.c, p.gravity)
    e["above_rest"] = energy_above_rest(tr["x1"], tr["v1"], tr["x2"], tr["v2"], p.m1, p.m2, p.c, p.gravity,
                                        p.suspension_stiffness)
    return e


def _save(fig, path):
    fig.tight_layout()
    return save_figure(fig, path)


def fig_3_1(off, on, scene, path):
    """Acceleration of body 1 (up positive: contact force / m1 - g) with and without control."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for run, label in ((off, "control off"), (on, "control on (thesis-ideal)")):
        t = t_ms(run)
        sel = (t >= -0.5) & (t <= 10)
        a1 = run.trace0["contact_force"] / scene.plant.m1 - scene.plant.gravity
        ax.plot(t[sel], a1[sel], label=label)
    ax.set_xlabel("time from first touch, ms")
    ax.set_ylabel("acceleration of body 1, m/s^2 (up)")
    ax.set_title("Fig 3.1 (ours): body 1's acceleration, ideal scene", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def fig_3_2(on, scene, path):
    """Six panels: (a) energies over the first 7 ms, (b) body 1's speed and catch energy over
    100 ms, (c) velocities, (d) displacements, (e) force, (f) its spectrum."""
    t = t_ms(on)
    e = body_energies(on, scene)
    tr = on.trace0
    fig, ax = plt.subplots(3, 2, figsize=(10, 9))
    a = ax[0, 0]
    sel = (t >= 0) & (t <= 7)
    for key, label in (("kinetic1", "kinetic, body 1"), ("kinetic2", "kinetic, body 2"),
                       ("elastic", "contact (elastic)")):
        a.plot(t[sel], e[key][sel] * 1e3, label=label)
    a.set_title("(a) energies, first 7 ms", fontsize=9)
    a.set_ylabel("energy, mJ")
    a = ax[0, 1]
    v0 = scene.impact_speed
    a.plot(t, np.abs(tr["v1"]) / v0, label="|v1| / impact speed")
    a.plot(t, e["catch"] / e["catch"][0], label="catch energy / impact energy")
    a.set_yscale("log")
    a.set_ylim(1e-5, 2)
    a.set_ylabel("ratio to the value at impact")
    a.set_title("(b) body 1 comes to rest", fontsize=9)
    a = ax[1, 0]
    a.plot(t, -tr["v1"], label="body 1")
    a.plot(t, -tr["v2"], label="body 2")
    a.set_title("(c) velocities (up positive)", fontsize=9)
    a.set_ylabel("velocity, m/s")
    a = ax[1, 1]
    a.plot(t, -tr["x1"] * 1e3, label="body 1")
    a.plot(t, -tr["x2"] * 1e3, label="body 2")
    a.set_title("(d) displacements of the facing surfaces (up positive)", fontsize=9)
    a.set_ylabel("height, mm")
    a = ax[2, 0]
    sel = (t >= 0) & (t <= 15)
    a.plot(t[sel], tr["force_applied"][sel])
    a.set_title("(e) shaker force on body 2 (up positive)", fontsize=9)
    a.set_ylabel("force, N")
    a = ax[2, 1]
    dt = float(on.trace_t[1] - on.trace_t[0])
    f, amp = force_asd(tr["force_applied"], dt)
    a.loglog(f[1:], np.maximum(amp[1:], 1e-9))
    a.axvspan(20, 1000, color="0.85", zorder=0, label="the thesis's 20-1000 Hz (sec 3.4)")
    a.set_xlim(3, 5e4)
    a.set_title("(f) force spectrum (amplitude spectral density, Welch)", fontsize=9)
    a.set_ylabel("amplitude density, N/sqrt(Hz)")
    a.set_xlabel("frequency, Hz")
    for a in ax.ravel():
        a.grid(alpha=0.3, which="both")
        if a is not ax[2, 1]:
            a.set_xlabel("time from first touch, ms")
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=7)
    fig.suptitle("Fig 3.2 (ours): thesis-ideal, sec 3.3 gains, ideal scene", fontsize=10)
    return _save(fig, path)


def fig_bounces(runs: dict, scene, path, title):
    """Fig 4.6/4.7 style: surfaces of both bodies (up positive) and body 1's velocity."""
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, run in runs.items():
        t = t_ms(run)
        tr = run.trace0
        (line,) = ax[0].plot(t, -tr["x1"] * 1e3, lw=1, label=f"{label}: body 1")
        ax[0].plot(t, -tr["x2"] * 1e3, lw=0.8, ls="--", color=line.get_color(), label=f"{label}: body 2")
        ax[1].plot(t, -tr["v1"], lw=1, color=line.get_color(), label=label)
    ax[0].set_ylabel("height of the surface, mm")
    ax[1].set_ylabel("velocity of body 1, m/s (up)")
    ax[1].set_xlabel("time from first touch, ms")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def fig_4_8(runs: dict, scene, path):
    """(a) body 1's catch energy over the episode, control off and on; (b) the first 10 ms;
    (c) the whole system's energy above rest (body 1's catch energy + body 2's kinetic and
    suspension energy), the thesis's 'total energy'."""
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    for label, run in runs.items():
        t = t_ms(run)
        e = body_energies(run, scene)
        (line,) = ax[0].plot(t, e["catch"] * 1e3, lw=1, label=label)
        sel = (t >= -1) & (t <= 10)
        ax[1].plot(t[sel], e["catch"][sel] * 1e3, lw=1, color=line.get_color(), label=label)
        total = e["above_rest"] / e["catch"][0]
        ax[2].semilogy(t, np.maximum(total, 1e-5), lw=1, color=line.get_color(), label=label)
    ax[0].set_title("(a) body 1's catch energy", fontsize=9)
    ax[1].set_title("(b) the first 10 ms", fontsize=9)
    ax[2].set_title("(c) the whole system's energy above rest (dotted: 1 %)", fontsize=9)
    ax[2].axhline(0.01, color="k", lw=0.6, ls=":")
    ax[0].set_ylabel("catch energy of body 1, mJ")
    ax[1].set_ylabel("catch energy of body 1, mJ")
    ax[2].set_ylabel("energy above rest / impact energy")
    for a in ax:
        a.set_xlabel("time from first touch, ms")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle("Fig 4.8 (ours): energy with and without control, rig scene", fontsize=10)
    return _save(fig, path)
