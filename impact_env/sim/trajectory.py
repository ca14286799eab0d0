"""A simulated drop as arrays over the record times, with its energies and summary metrics."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from impact_env.hardware.stability import accuracy_warnings
from impact_env.plant.dynamics import contact_forces
from impact_env.plant.energy import catch_energy, energies, energy_above_rest
from impact_env.plant.layout import AUTO, CONTACT, PARAM, STATE
from impact_env.scene import Scene
from impact_env.scene.scene import ADAPTIVE

# a run whose energy ledger misses more than this (relative to the larger of the initial total
# and catch energies) is flagged: every converged setting stays below 1e-6 (RK4 at 1 us: 1e-10)
ENERGY_BALANCE_BOUND = 1e-3


@dataclass
class Trajectory:
    """A simulated run, sampled at the record rate (state at each sample time).

    Frame: x down, body 2's rest surface at 0; ``d = x1 - x2`` is the penetration.
    ``events`` has one row per contact onset (+1) or separation (-1): t (s), kind, x1, v1, x2, v2.
    """

    t: np.ndarray  # s
    x1: np.ndarray  # m
    v1: np.ndarray  # m/s
    x2: np.ndarray  # m
    v2: np.ndarray  # m/s
    contact: np.ndarray  # bool, in contact at the sample
    contact_force: np.ndarray  # N, at the sample
    peak_force: np.ndarray  # N, largest contact force seen within the interval ending at the sample
    shaker_force: np.ndarray  # N (upwards), held over the interval ending at the sample
    work_shaker: np.ndarray  # J, work done by the shaker since t = 0
    dissipated: np.ndarray  # J, energy dissipated since t = 0
    events: np.ndarray
    t_first_contact: float  # s, the time of the first touch (from the initial condition)
    scene: Scene
    params: np.ndarray
    wall_time_s: float = 0.0
    n_events_dropped: int = 0
    # the largest penetration, m, tracked by the integrator at every step (not from the records)
    peak_penetration: float = float("nan")

    @property
    def penetration(self) -> np.ndarray:
        return self.x1 - self.x2

    def energies(self) -> dict[str, np.ndarray]:
        p = self.params
        return energies(self.x1, self.v1, self.x2, self.v2, p[PARAM.m1], p[PARAM.m2], p[PARAM.c], p[PARAM.g],
                        p[PARAM.k2])

    def catch_energy(self) -> np.ndarray:
        """Body 1's energy above resting on body 2 (J); see :func:`plant.energy.catch_energy`."""
        p = self.params
        return catch_energy(self.x1, self.v1, self.x2, p[PARAM.m1], p[PARAM.c], p[PARAM.g])

    def energy_balance_error(self) -> float:
        """max |E(t) + dissipated(t) - work_shaker(t) - E(0)| / E_scale over the run, E_scale the
        larger of the initial total and the initial catch energy."""
        e = self.energies()["total"]
        resid = e + self.dissipated - self.work_shaker - e[0]
        scale = max(abs(e[0]), float(self.catch_energy()[0]), 1e-300)
        return float(np.max(np.abs(resid)) / scale)

    def onsets(self) -> np.ndarray:
        return self.events[self.events[:, 1] > 0]

    def separations(self) -> np.ndarray:
        return self.events[self.events[:, 1] < 0]

    def restitution(self) -> float | None:
        """Relative separation speed over relative impact speed at the first separation."""
        on, off = self.onsets(), self.separations()
        if len(on) == 0 or len(off) == 0:
            return None
        vin = on[0, 3] - on[0, 5]
        first_off = off[off[:, 0] > on[0, 0]]
        if len(first_off) == 0 or vin == 0:
            return None
        return float(-(first_off[0, 3] - first_off[0, 5]) / vin)

    def first_contact_duration(self) -> float | None:
        on, off = self.onsets(), self.separations()
        if len(on) == 0:
            return None
        later = off[off[:, 0] > on[0, 0]]
        return float(later[0, 0] - on[0, 0]) if len(later) else None

    def max_penetration(self) -> float:
        """Largest penetration (m): the integrator's own maximum over every step (and the top
        between two steps where the penetration turned), so a contact shorter than the record
        period is not under-reported; without it (a trajectory built elsewhere), from the
        samples, refined by a parabola through the three at the peak."""
        if math.isfinite(self.peak_penetration):
            return float(max(self.peak_penetration, float(np.max(self.penetration))))
        d = self.penetration
        k = int(np.argmax(d))
        if 0 < k < len(d) - 1:
            a, b, c = d[k - 1], d[k], d[k + 1]
            den = a - 2 * b + c
            if den < 0:
                return float(b - 0.125 * (c - a) ** 2 / den)
        return float(d[k])

    def energy_above_rest(self) -> np.ndarray:
        """The system's energy above rest (J), see :func:`plant.energy.energy_above_rest`."""
        p = self.params
        return energy_above_rest(self.x1, self.v1, self.x2, self.v2, p[PARAM.m1], p[PARAM.m2], p[PARAM.c],
                                 p[PARAM.g],
                                 p[PARAM.k2])

    def time_to_fraction(self, fraction: float = 0.01) -> float | None:
        """Time (s) from the first touch until the system's energy above rest
        (:meth:`energy_above_rest`) first falls below ``fraction`` of body 1's impact energy
        (its catch energy at the start), interpolated linearly between records; None if it
        does not within the run.

        Without shaker force that energy never rises, so the time is final: every run long
        enough to contain it gives the same time, and body 1's catch energy (never above the
        system's, with a suspension) stays below the fraction from then on.  With a controller
        the shaker can put energy back, and the time is that of the first crossing only (the
        env's and ``compare``'s catch asks for 10 ms below 1 %).
        """
        e = self.energy_above_rest()
        thr = fraction * float(self.catch_energy()[0])
        below = np.nonzero(e < thr)[0]
        if len(below) == 0:
            return None
        k = int(below[0])
        if k == 0:
            t = self.t[0]
        else:
            a, b = e[k - 1], e[k]
            t = self.t[k - 1] + (a - thr) / (a - b) * (self.t[k] - self.t[k - 1])
        return float(max(t - self.t_first_contact, 0.0))

    def warnings(self) -> list[str]:
        """What makes this run's numbers doubtful, in words (empty when nothing does): the
        integrator's settings where they are known to be inaccurate although the ledger may
        balance (:func:`impact_env.hardware.stability.accuracy_warnings`), an energy ledger that
        misses more than ``ENERGY_BALANCE_BOUND`` of the energy, events beyond the buffer."""

        out = accuracy_warnings(self.scene)
        err = self.energy_balance_error()
        if not err <= ENERGY_BALANCE_BOUND:
            integ = self.scene.integrator
            step = f"rtol {integ.rtol:g}" if integ.method in ADAPTIVE else f"dt {integ.dt:g} s"
            why = (" (explicit Euler, thesis eq 3.8, gains energy at every contact)"
                   if integ.method == "euler" else "")
            out.append(f"energy balance error {err:.3g} exceeds {ENERGY_BALANCE_BOUND:g}: {integ.method} at "
                       f"{step} is not accurate here{why}; the energies, restitution and times are off "
                       f"by about as much (use integrator.method = rk4 or a smaller step)")
        if self.n_events_dropped:
            out.append(f"{self.n_events_dropped} contact events beyond the event buffer were not "
                       "recorded (restitution and contact counts miss them)")
        return out

    def metrics(self) -> dict:
        """The summary of a drop (the fields ``impact-env drop --json`` prints)."""
        return {
            "max_penetration_m": self.max_penetration(),
            "first_contact_duration_s": self.first_contact_duration(),
            "peak_contact_force_N": float(max(self.peak_force.max(), self.contact_force.max())),
            "restitution": self.restitution(),
            "energy_balance_error": self.energy_balance_error(),
            "time_to_1pct_energy_s": self.time_to_fraction(0.01),
            "n_contacts": int(len(self.onsets())),
            "wall_time_s": self.wall_time_s,
            "warnings": self.warnings(),
        }


def build_trajectory(scene, p, out_y, out_mode, out_peak, f2_rec, ev, evn, t_touch, rec_period, wall,
                     peak_penetration: float = float("nan")):
    n = out_y.shape[0]
    t = np.arange(n) * rec_period
    x1, v1, x2, v2 = (out_y[:, j].copy() for j in range(4))
    d = x1 - x2
    mode = out_mode
    fc = np.empty(n)
    contact_forces(d, v1 - v2, mode.astype(np.int64), p[PARAM.c], p[PARAM.b], fc)
    contact = (mode == CONTACT) if mode[0] != AUTO else (fc > 0)
    k = int(min(evn[0], ev.shape[0]))
    return Trajectory(t=t, x1=x1, v1=v1, x2=x2, v2=v2, contact=contact, contact_force=fc,
                      peak_force=out_peak.copy(), shaker_force=f2_rec, work_shaker=out_y[:,
                                                                                         STATE.w_ext].copy(),
                      dissipated=out_y[:, STATE.w_diss].copy(), events=ev[:k].copy(), t_first_contact=t_touch,
                      scene=scene, params=p, wall_time_s=wall, n_events_dropped=int(evn[0]) - k,
                      peak_penetration=peak_penetration)
