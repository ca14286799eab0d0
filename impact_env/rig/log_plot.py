"""A picture of one rig episode log (matplotlib, imported lazily)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from impact_env.plant.energy import catch_energy
from impact_env.rig.flight_energy import Plant, contact_from_log, estimate_energy


def plot_log(log, path, estimate: dict | None = None) -> Path:
    """Three panels over time from the release: body 2's raw sensors (acceleration, transducer
    force, travel), the demanded and applied force (a force that is 0 N throughout is named in
    the title, not drawn; with neither, the panel is left out), and body 1's energy over its
    impact energy (estimated from the flight times; true too, from a virtual rig).  ``path``'s
    suffix picks png, pdf or svg (:func:`impact_env.figstyle.save_figure`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from impact_env.figstyle import save_figure  # matplotlib's: loaded to plot, not with the CLI

    t_ms = log["t_s"] * 1e3
    # as compare's force plot: a force that is zero throughout (a passive policy) is named in the
    # title, not drawn as a flat line at 0 that reads like data; with neither force, no force panel
    forces = [(col, label, color) for col, label, color in
              (("force_demand_N", "demanded (after safety)", "tab:blue"),
               ("force_applied_N", "applied", "tab:orange")) if np.any(log[col] != 0.0)]
    silent = [word for col, word in (("force_demand_N", "demanded"), ("force_applied_N", "applied"))
              if not np.any(log[col] != 0.0)]
    fig, axs = plt.subplots(3 if forces else 2, 1, figsize=(9, 8 if forces else 5.6), sharex=True)
    ax = list(axs)
    ax[0].plot(t_ms, log["force_N"], lw=0.8, label="force transducer, N")
    ax[0].plot(t_ms, log["accelerometer_mps2"] * 0.1, lw=0.8, label="accelerometer x 0.1, m/s^2")
    ax0b = ax[0].twinx()
    ax0b.plot(t_ms, log["potentiometer_m"] * 1e3, lw=0.8, color="0.4", label="potentiometer, mm")
    ax0b.set_ylabel("body 2 travel, mm (down)")
    ax[0].set_ylabel("raw reading")
    ax[0].legend(loc="upper left", fontsize=7)
    ax0b.legend(loc="upper right", fontsize=7)
    if forces:
        for col, label, color in forces:
            ax[1].plot(t_ms, log[col], lw=0.8, label=label, color=color)
        ax[1].set_ylabel("force on body 2, N (up)")
        ax[1].legend(fontsize=7)
    e_ax = ax[-1]
    scene = log.scene()
    plant = Plant.of(scene)
    est = estimate_energy(log["t_s"], contact_from_log(log), plant, log["potentiometer_m"])
    e_ax.semilogy(t_ms, np.maximum(est.energy_J / est.e0_J, 1e-6), lw=1,
                   label="estimated (thesis eq 4.5, ballistic)")
    if "true_x1_m" in log.columns:
        p = scene.plant
        e = catch_energy(log["true_x1_m"], log["true_v1_mps"], log["true_x2_m"], p.m1, p.c, p.gravity)
        e_ax.semilogy(t_ms, np.maximum(e / log["impact_energy_J"][0], 1e-6), lw=1,
                      label="true (virtual rig)")
    e_ax.axhline(0.01, color="k", lw=0.6, ls=":")
    e_ax.set_ylabel("body 1's energy / impact energy")
    e_ax.set_xlabel("time from the release, ms")
    e_ax.legend(fontsize=7)
    for a in ax:
        a.grid(alpha=0.3)
    m = log.meta
    quiet = f"; no force {' or '.join(silent)} (0 N throughout)" if silent else ""
    fig.suptitle(f"rig episode {m.episode}: {m.mode} mode, seed {m.seed}, ended by {m.end_reason}{quiet}",
                 fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)
