"""Plots of trajectories (matplotlib, imported lazily so that the core never needs it)."""

from __future__ import annotations

from impact_env.figstyle import save_figure


def plot_trajectory(traj, path: str) -> None:
    """Positions, velocities, forces and energies over time, in the style of thesis fig 3.2."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_ms = (traj.t - traj.t_first_contact) * 1e3
    fig, ax = plt.subplots(4, 1, figsize=(8, 10), sharex=True)
    ax[0].plot(t_ms, -traj.x1 * 1e3, label="body 1 (surface)")
    ax[0].plot(t_ms, -traj.x2 * 1e3, label="body 2 (surface)")
    ax[0].set_ylabel("height, mm (up)")
    ax[1].plot(t_ms, -traj.v1, label="body 1")
    ax[1].plot(t_ms, -traj.v2, label="body 2")
    ax[1].set_ylabel("velocity, m/s (up)")
    ax[2].plot(t_ms, traj.contact_force, label="contact force")
    ax[2].plot(t_ms, traj.shaker_force, label="shaker force (up)")
    ax[2].set_ylabel("force, N")
    e = traj.energies()
    for key, label in (("kinetic1", "kinetic, body 1"), ("kinetic2", "kinetic, body 2"),
                       ("elastic", "elastic, pad"), ("suspension", "suspension spring")):
        if e[key].max() > 0:
            ax[3].plot(t_ms, e[key] * 1e3, label=label)
    ax[3].plot(t_ms, traj.catch_energy() * 1e3, "k--", label="catch energy of body 1")
    ax[3].set_ylabel("energy, mJ")
    ax[3].set_xlabel("time from first touch, ms")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"scene {traj.scene.name}: drop at {traj.scene.impact_speed:.3g} m/s")
    fig.tight_layout()

    save_figure(fig, path)
