"""A picture of one rig episode log (matplotlib, imported lazily)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_log(log, path, estimate: dict | None = None) -> Path:
    """Three panels over time from the release: body 2's raw sensors (acceleration, transducer
    force, travel), the demanded and applied force, and body 1's energy over its impact energy
    (estimated from the flight times; true too, from a virtual rig)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from impact_env.rig.energy import Plant, contact_from_log, estimate_energy

    t_ms = log["t_s"] * 1e3
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax[0].plot(t_ms, log["force_N"], lw=0.8, label="force transducer, N")
    ax[0].plot(t_ms, log["accelerometer_mps2"] * 0.1, lw=0.8, label="accelerometer x 0.1, m/s^2")
    ax0b = ax[0].twinx()
    ax0b.plot(t_ms, log["potentiometer_m"] * 1e3, lw=0.8, color="0.4", label="potentiometer, mm")
    ax0b.set_ylabel("body 2 travel, mm (down)")
    ax[0].set_ylabel("raw reading")
    ax[0].legend(loc="upper left", fontsize=7)
    ax0b.legend(loc="upper right", fontsize=7)
    ax[1].plot(t_ms, log["force_demand_N"], lw=0.8, label="demanded (after safety)")
    ax[1].plot(t_ms, log["force_applied_N"], lw=0.8, label="applied")
    ax[1].set_ylabel("force on body 2, N (up)")
    ax[1].legend(fontsize=7)
    scene = log.scene()
    plant = Plant.of(scene)
    est = estimate_energy(log["t_s"], contact_from_log(log), plant, log["potentiometer_m"])
    ax[2].semilogy(t_ms, np.maximum(est.energy_J / est.e0_J, 1e-6), lw=1,
                   label="estimated (thesis eq 4.5, ballistic)")
    if "true_x1_m" in log.columns:
        from impact_env.plant.energy import catch_energy

        p = scene.plant
        e = catch_energy(log["true_x1_m"], log["true_v1_mps"], log["true_x2_m"], p.m1, p.c, p.gravity)
        ax[2].semilogy(t_ms, np.maximum(e / log["impact_energy_J"][0], 1e-6), lw=1,
                       label="true (virtual rig)")
    ax[2].axhline(0.01, color="k", lw=0.6, ls=":")
    ax[2].set_ylabel("body 1's energy / impact energy")
    ax[2].set_xlabel("time from the release, ms")
    ax[2].legend(fontsize=7)
    for a in ax:
        a.grid(alpha=0.3)
    m = log.meta
    fig.suptitle(f"rig episode {m.episode}: {m.mode} mode, seed {m.seed}, ended by {m.end_reason}",
                 fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=150, bbox_inches="tight")  # impact_env.eval.figstyle's style (rig sits below eval)
    plt.close(fig)
    return path
