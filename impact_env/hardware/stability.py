"""Refusing, before simulating, a fixed step that the drop's contact would make unstable or
leave unresolved.

Two checks, both from the contact law ``F = c d^1.5 + b d^0.25 d'`` (clipped at 0) and the
drop the scene describes; both raise :class:`~impact_env.config.ConfigError` naming
``integrator.dt``, what failed and the step that would pass.

**Stability.**  Linearised about a penetration d, the pad is a spring ``k = 1.5 c d^0.5`` (N/m)
and a damper ``b d^0.25`` (N s/m) between the bodies; with body 2's suspension (k2, c2) the
plant is the linear system ``y' = A(d) y`` in ``y = (x1, v1, x2, v2)``.  A fixed-step method
maps it through its one-step matrix ``M(h A)``; the step is stable for that d if the spectral
radius of M is at most 1:

* RK4: ``M = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24`` (eigenvalues ``R(h lambda)``, the
  stability polynomial ``|1 + z + z^2/2 + z^3/6 + z^4/24| <= 1``: ``omega h <= 2 sqrt 2`` on an
  undamped oscillation, ``-2.785 <= z`` on a pure decay);
* symplectic Euler: velocities first, then positions with the new velocities, whose matrix
  (``omega h <= 2`` undamped) is built as such;
* explicit Euler (thesis eq 3.8), eigenvalues ``1 + h lambda``: it is unstable on every
  undamped oscillation, which is the error the thesis shows, so it is held to the growth it
  has on an oscillation with ``omega h = 1`` and no more: ``|Im h lambda| <= 1`` and
  ``-2 <= Re h lambda`` (inside its real interval).

Every penetration from 0 (free flight: the suspension alone) to the deepest one the drop
reaches is checked (a geometric grid): the deepest is that of the scaled Tsuji collision
(:func:`~impact_env.plant.restitution.scaled_collision`) with gravity's extra work, and at least
``(2.5 m1 g / c)^(2/3)``, the deepest point of body 1 dropped onto the pad from touching (1.84
times its resting penetration).  A shaker force can press deeper than that; such a run is
caught while simulating (``SimulationDiverged``).

**Resolution.**  A contact taken in too few steps is stable but wrong: RK4 with event location
misses the restitution by up to 1.2e-2 with 4 steps per contact, 4.4e-3 with 5, 2.0e-3 with 6,
5.4e-4 with 8 and 2.0e-4 with 10 (worst over seven touch phases and restitutions 1, 0.8 and
0.3; ``python scripts/steps_per_contact.py``, tested in ``tests/test_stability.py``).  So
``integrator.min_steps_per_contact`` (default 8: restitution within about 1e-3) is required of
the shortest contact: the impact at the scene's speed (contact time of the scaled collision
for the pad's damping) and, under gravity, the oscillation of body 1 resting on the pad
(period ``2 pi / omega`` at the resting penetration).  Explicit and symplectic Euler are held to
the same count: they are less accurate still, which the energy ledger's warning reports.

A randomised scene is checked at every corner of its ranges on m1, c, the drop, the
restitution and the suspension (the eigenvalues and the contact time are monotone in each).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np

from impact_env.config import ConfigError
from impact_env.scene.scene import ADAPTIVE
from impact_env.plant.restitution import scaled_collision, zeta_for_restitution

N_GRID = 40  # penetrations checked: d_max * 2^-k, k = 0 .. N_GRID - 1, and 0
RHO_TOL = 1e-9  # a spectral radius up to 1 + RHO_TOL counts as stable (neutral modes sit at 1)
# the free drift of the bodies (lambda = 0, a Jordan block of A) maps to an eigenvalue 1 of the
# step matrix that eigvals returns only to about sqrt(eps): eigenvalues within this of 1 are
# that neutral mode (a method's instability sets in at |h lambda| of order 1, far from mu = 1)
NEUTRAL = 1e-6
# largest stable omega*dt of each fixed-step method on an undamped oscillation (what
# stable() gives with no damping): RK4 2 sqrt 2, symplectic Euler 2, explicit Euler's bound 1
STABILITY_LIMIT = {"euler": 1.0, "symplectic-euler": 2.0, "rk4": 2.0 * math.sqrt(2.0)}
PLANT_RANGES = ("m1", "c", "drop_height", "impact_speed", "restitution", "suspension_stiffness",
                "suspension_damping")


@dataclass(frozen=True)
class Drop:
    """What the checks need of a scene: masses (kg), pad c (N/m^1.5) and restitution, gravity
    (m/s^2), suspension k2 (N/m) and c2 (N s/m), impact speed (m/s)."""

    m1: float
    m2: float
    c: float
    restitution: float
    gravity: float
    k2: float
    c2: float
    v: float

    @classmethod
    def of(cls, scene) -> Drop:
        pl = scene.plant
        return cls(pl.m1, pl.m2, pl.c, pl.restitution, pl.gravity, pl.suspension_stiffness,
                   pl.suspension_damping, scene.impact_speed)

    @property
    def m(self) -> float:
        return self.m1 * self.m2 / (self.m1 + self.m2)

    def describe(self) -> str:
        """The drop in the scene's field names, for messages."""
        return (f"plant.m1 = {self.m1:g} kg, plant.m2 = {self.m2:g} kg, plant.c = {self.c:g} N/m^1.5, "
                f"plant.restitution = {self.restitution:g}, plant.suspension_stiffness = {self.k2:g} N/m, "
                f"plant.suspension_damping = {self.c2:g} N s/m, impact speed {self.v:g} m/s "
                "(initial.drop_height or initial.impact_speed)")


def linear_matrix(m1, m2, k, cd, k2: float, c2: float) -> np.ndarray:
    """``A`` of the plant linearised about a penetration: pad spring k (N/m) and damper cd
    (N s/m) between the bodies, suspension k2, c2 on body 2; state (x1, v1, x2, v2).  k and cd
    may be arrays (one matrix per entry: shape (n, 4, 4))."""
    k = np.asarray(k, dtype=float)
    cd = np.asarray(cd, dtype=float)
    A = np.zeros(k.shape + (4, 4))
    A[..., 0, 1] = 1.0
    A[..., 1, 0] = -k / m1
    A[..., 1, 1] = -cd / m1
    A[..., 1, 2] = k / m1
    A[..., 1, 3] = cd / m1
    A[..., 2, 3] = 1.0
    A[..., 3, 0] = k / m2
    A[..., 3, 1] = cd / m2
    A[..., 3, 2] = -(k + k2) / m2
    A[..., 3, 3] = -(cd + c2) / m2
    return A


def step_matrix(method: str, hA: np.ndarray) -> np.ndarray:
    """One-step matrix of ``method`` on ``y' = A y`` for the step-scaled ``hA`` (..., 4, 4)."""
    eye = np.broadcast_to(np.eye(4), hA.shape)
    if method == "rk4":
        m = eye.copy()
        term = eye
        for j in range(1, 5):
            term = term @ hA / j
            m = m + term
        return m
    if method == "euler":
        return eye + hA
    if method == "symplectic-euler":
        # v_new = v + (hA y)_v; x_new = x + h v_new (= x + (hA y)_x evaluated at v_new)
        m = eye.copy()
        vel, pos = [1, 3], [0, 2]
        m[..., vel, :] += hA[..., vel, :]
        m[..., pos, :] = eye[..., pos, :] + hA[..., pos, :][..., :, vel] @ m[..., vel, :]
        return m
    raise ValueError(f"no step matrix for method {method!r}")


def stable(method: str, hA: np.ndarray) -> bool | np.ndarray:
    """Whether ``method``'s step is stable on ``y' = A y``, per matrix of the stack ``hA``
    (see the module doc)."""
    hA = np.asarray(hA, dtype=float)
    single = hA.ndim == 2
    hA = hA.reshape((-1, 4, 4))
    if method == "euler":
        z = np.linalg.eigvals(hA)
        drift = np.abs(z) <= NEUTRAL
        ok = ((np.abs(z.imag) <= 1.0 + RHO_TOL) & (z.real >= -2.0 - RHO_TOL)) | drift
    else:
        mu = np.linalg.eigvals(step_matrix(method, hA))
        ok = (np.abs(mu) <= 1.0 + RHO_TOL) | (np.abs(mu - 1.0) <= NEUTRAL)
    res = np.all(ok, axis=-1)
    return bool(res[0]) if single else res


def contact_scales(drop: Drop) -> dict:
    """The drop's contact as the checks see it: pad damping b (N s/m^1.25), deepest
    penetration (m), shortest contact time (s) and what sets it."""
    m, v = drop.m, drop.v
    zeta = zeta_for_restitution(drop.restitution) if drop.restitution < 1.0 else 0.0
    b = zeta * math.sqrt(m * drop.c)
    d_max, t_c, what = 0.0, math.inf, ""
    if v > 0:
        col = scaled_collision(zeta)
        mc = (m / drop.c) ** 0.4
        d_max = mc * v**0.8 * col.s_max  # D s_max, D = (m v^2 / c)^(2/5)
        if drop.gravity > 0:  # gravity's work on the way in: 0.4 c d^2.5 = 0.5 m v^2 + m g d (elastic)
            d_max = _deepest_elastic(m, drop.c, v, drop.gravity) * col.s_max / scaled_collision(0.0).s_max
        t_c, what = mc * v**-0.2 * col.tau_contact, f"the impact at {v:.3g} m/s"
    if drop.gravity > 0:
        d_rest = (2.5 * drop.m1 * drop.gravity / drop.c) ** (2.0 / 3.0)
        d_max = max(d_max, d_rest)
        ds = (drop.m1 * drop.gravity / drop.c) ** (2.0 / 3.0)
        period = 2.0 * math.pi / math.sqrt(1.5 * drop.c * math.sqrt(ds) / m)
        if period < t_c:
            t_c, what = period, "the oscillation of body 1 resting on the pad"
    return {"b": b, "d_max": d_max, "t_contact": t_c, "what": what}


def _deepest_elastic(m: float, c: float, v: float, g: float) -> float:
    """Root of ``0.4 c d^2.5 - m g d - 0.5 m v^2 = 0`` (m), by Newton from the larger of the
    Hertz value and ``(2.5 m g / c)^(2/3)``, both below the root and right of f's minimum (f is
    convex there, so Newton converges from the right after its first step)."""
    d = max((1.25 * m * v * v / c) ** 0.4, (2.5 * m * g / c) ** (2.0 / 3.0))
    for _ in range(100):
        f = 0.4 * c * d**2.5 - m * g * d - 0.5 * m * v * v
        df = c * d**1.5 - m * g
        step = f / df
        d -= step
        if abs(step) <= 1e-15 * d:
            break
    return d


def _grid(d_max: float) -> np.ndarray:
    return np.array([d_max * 2.0**-k for k in range(N_GRID)] + [0.0]) if d_max > 0 else np.zeros(1)


def first_unstable(drop: Drop, method: str, dt: float, d_max: float, b: float) -> float | None:
    """The deepest penetration (m) in [0, d_max] at which the step dt is unstable, or None."""
    d = _grid(d_max)
    A = linear_matrix(drop.m1, drop.m2, 1.5 * drop.c * np.sqrt(d), b * d**0.25, drop.k2, drop.c2)
    ok = np.asarray(stable(method, dt * A))
    return None if ok.all() else float(d[np.argmin(ok)])


def max_stable_dt(drop: Drop, method: str, d_max: float, b: float) -> float:
    """The largest step (s) that is stable at every penetration in [0, d_max] (bisection in
    log dt; inf if a step of 1 s is)."""
    def ok(dt: float) -> bool:
        return first_unstable(drop, method, dt, d_max, b) is None

    hi = 1.0
    if ok(hi):
        return math.inf
    lo = hi
    while not ok(lo):
        lo *= 0.5
        if lo < 1e-300:
            return 0.0
        hi = 2.0 * lo
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
        if hi / lo < 1.0 + 1e-6:
            break
    return lo


# dopri5: its position error grows in proportion to rtol, about 1.6e3 rtol of the deepest
# penetration on `rig` (1.6e-3 at rtol 1e-6, 1.8e-4 at 1e-7, 1.7e-5 at 1e-8, 1.6e-6 at 1e-9, against
# rtol 1e-12: tests/test_trust_results.py measures it); above DOPRI_MAX_RTOL it passes 1e-4
DOPRI_ERROR_PER_RTOL = 1.6e3
DOPRI_MAX_RTOL = 1e-7
DOPRI_SAFE_RTOL = 1e-8
# without event location a fixed step crosses each switch blind: one step's error at each end of a
# contact, so an elastic pad needs this many steps per contact for a contact time within 1e-3
NO_EVENT_MIN_STEPS = 2000


def accuracy_warnings(scene) -> list[str]:
    """Settings the scene accepts (they are stable, and some tests and comparisons want them)
    whose results are nevertheless off by more than the energy ledger shows, in words: dopri5
    above ``DOPRI_MAX_RTOL``; a fixed step without event location on a damped pad (a different
    contact model: the damping keeps pulling while body 1 is inside the pad), or with fewer than
    ``NO_EVENT_MIN_STEPS`` steps per contact on an elastic one."""
    integ = scene.integrator
    out = []
    if integ.method in ADAPTIVE:
        if integ.rtol > DOPRI_MAX_RTOL:
            out.append(f"integrator.rtol = {integ.rtol:g} is loose for a contact: dopri5's position error "
                       f"is about {DOPRI_ERROR_PER_RTOL:g} rtol = {DOPRI_ERROR_PER_RTOL * integ.rtol:.2g} "
                       "of the deepest penetration here (measured on rig); use integrator.rtol <= "
                       f"{DOPRI_SAFE_RTOL:g}")
        return out
    if integ.event_location:
        return out
    drop = Drop.of(scene)
    if drop.restitution < 1.0:
        out.append(f"integrator.event_location = false on a damped pad (restitution {drop.restitution:g}): "
                   "stepping across the separation, the pad's damping keeps pulling body 1 while it is "
                   "inside the pad, where the located model lets go when the force reaches zero; "
                   "contact times are then about 8 % off and the restitution about 5e-3, whatever the dt (measured on rig from "
                   "35 to 3500 steps per contact); use integrator.event_location = true")
        return out
    sc = contact_scales(drop)
    steps = sc["t_contact"] / integ.dt
    if math.isfinite(steps) and steps < NO_EVENT_MIN_STEPS:
        out.append(f"integrator.event_location = false with {steps:.3g} steps per contact: each switch costs "
                   f"up to a step, about {2.0 / steps:.1g} of the contact time; use integrator.dt <= "
                   f"{_down(sc['t_contact'] / NO_EVENT_MIN_STEPS)} s or integrator.event_location = true")
    return out


def check_step(scene) -> None:
    """Refuse (ConfigError) a fixed step that is unstable or resolves the shortest contact
    with fewer than ``integrator.min_steps_per_contact`` steps, for the scene and, if it is
    randomised, every corner of its plant ranges.  dopri5 is not checked (adaptive)."""
    integ = scene.integrator
    if integ.method in ADAPTIVE:
        return
    corners = list(_corners(scene))
    for drop, label in corners:
        try:
            _check_one(integ, drop, label, scene.control_period)
        except ConfigError as exc:
            # one dt for the whole scene: stable and resolved at every corner, on the control grid
            safe = min(_safe_dt(integ, d, scene.control_period) for d, _ in corners)
            raise ConfigError(f"{exc} A step that passes every check of this scene: integrator.dt = "
                              f"{_grid_text(safe, scene.control_period)}.") from None


def _safe_dt(integ, drop: Drop, period: float | None) -> float:
    """The largest step that is stable and resolves the contact for ``drop``, on the grid."""
    sc = contact_scales(drop)
    dt = max_stable_dt(drop, integ.method, sc["d_max"], sc["b"])
    need = integ.min_steps_per_contact
    if need > 0 and math.isfinite(sc["t_contact"]):
        dt = min(dt, sc["t_contact"] / need)
    return _fits(dt, period)


def _corners(scene):
    base = Drop.of(scene)
    yield base, ""
    rz = scene.randomize
    names = [n for n in rz.ranged() if n in PLANT_RANGES]
    if not names:
        return
    target = {"m1": "m1", "c": "c", "restitution": "restitution", "suspension_stiffness": "k2",
              "suspension_damping": "c2"}
    for ends in itertools.product((0, 1), repeat=len(names)):
        values = {n: getattr(rz, n)[e] for n, e in zip(names, ends, strict=True)}
        fields = {target[n]: v for n, v in values.items() if n in target}
        if "drop_height" in values:
            fields["v"] = math.sqrt(2.0 * base.gravity * values["drop_height"])
        if "impact_speed" in values:
            fields["v"] = values["impact_speed"]
        label = " at the corner of the randomize ranges " + ", ".join(
            f"randomize.{n} = {v:g}" for n, v in values.items())
        yield dataclasses.replace(base, **fields), label


def _down(x: float) -> str:
    """``x`` rounded down to three significant digits (a step printed as a bound must pass)."""
    if not (x > 0 and math.isfinite(x)):
        return f"{x:g}"
    e = math.floor(math.log10(x)) - 2
    return f"{math.floor(x / 10.0**e) * 10.0**e:.3g}"


def _fits(dt: float, period: float | None) -> float:
    """The largest step <= dt that divides the control period (the grid every scene needs)."""
    if not period or not (dt > 0):
        return dt
    return period / math.ceil(period / dt * (1.0 - 1e-12))


def _grid_text(dt: float, period: float | None) -> str:
    """A suggested step as text that passes when typed back: on the control grid, exactly."""
    if period and dt > 0:
        n = round(period / dt)
        return f"{period / n!r} s (the control period / {n})"
    return f"{_down(dt)} s"


def _check_one(integ, drop: Drop, label: str, period: float | None = None) -> None:
    method, dt = integ.method, integ.dt
    sc = contact_scales(drop)
    bad_d = first_unstable(drop, method, dt, sc["d_max"], sc["b"])
    if bad_d is not None:
        limit = max_stable_dt(drop, method, sc["d_max"], sc["b"])
        if integ.min_steps_per_contact > 0 and math.isfinite(sc["t_contact"]):
            # suggest a dt the resolution check below, and the control grid, accept too
            limit = min(limit, sc["t_contact"] / integ.min_steps_per_contact)
        limit = _fits(limit, period)
        k = 1.5 * drop.c * math.sqrt(bad_d)
        cd = sc["b"] * bad_d**0.25
        lam = np.linalg.eigvals(linear_matrix(drop.m1, drop.m2, k, cd, drop.k2, drop.c2))
        fastest = lam[np.argmax(np.abs(lam))]
        raise ConfigError(
            f"integrator.dt = {dt:g} s is beyond the stability limit of {method}{label}: at a "
            f"penetration of {bad_d:.3g} m (pad stiffness {k:.3g} N/m, pad damping {cd:.3g} N s/m, "
            f"deepest penetration of the drop {sc['d_max']:.3g} m) the fastest mode has "
            f"h*lambda = {dt * fastest:.3g}, outside the method's stability region; it needs "
            f"dt <= {_grid_text(limit, period)}. Reduce integrator.dt or use integrator.method = dopri5. "
            f"The drop: {drop.describe()}.")
    need = integ.min_steps_per_contact
    if need > 0 and math.isfinite(sc["t_contact"]):
        steps = sc["t_contact"] / dt
        if steps < need:
            raise ConfigError(
                f"integrator.dt = {dt:g} s resolves {sc['what']}{label} (about {sc['t_contact']:.3g} s "
                f"of contact) with {steps:.3g} steps, fewer than integrator.min_steps_per_contact = "
                f"{need:g} (below that RK4's restitution error exceeds about 1e-3): use "
                f"integrator.dt <= {_down(_fits(sc['t_contact'] / need, period))} s, or "
                "integrator.method = dopri5. "
                f"The drop: {drop.describe()}.")
