"""The staged fit of a scene to identification experiments, with uncertainties.

Stages (each on the experiments that inform it, the earlier stages' results fixed):

1. **Sensors** (quiet episodes: body 1 held, 0 N): per channel the offset (the mean) and the
   noise (the standard deviation, less the ADC quantum's ``q^2/12``), in closed form, with
   their standard errors ``s/sqrt(n)`` and ``s/sqrt(2(n-1))``.  The total standard deviation
   (noise and quantum) weights that channel's residuals in the next stages, so the fit is the
   maximum-likelihood one for white Gaussian noise.
2. **Shaker** (shaker-only episodes): body 2's acceleration per unit command, the suspension's
   ``k2/m2`` and ``c2/m2``, the shaker's band edges and coil inductance, the transducer's top
   mass m2' and the total delay (whole ticks, the one that fits best), by
   :func:`scipy.optimize.least_squares` on the three channels.
3. **Drops** (identification drops, passive): m2, m1, the pad's c and restitution and the sensor
   delay, started from the drops' own timing (thesis eq 4.5: the flight time gives the rebound
   speed, the contact force's impulse m1, its duration c through Hertz) and refined the same
   way; the shaker stage's ratios are kept.
4. **Joint**: every continuous parameter on every experiment at once, from the stages' values:
   the covariance ``s^2 (J^T J)^-1`` of its Jacobian (``s^2`` the reduced chi-square) gives each
   value's standard uncertainty.  A parameter whose relative uncertainty exceeds
   :data:`IDENTIFIED_REL` is not identified by these logs: it is reported, kept at the base
   value, and the fit is repeated without it.

The Jacobian is taken by forward differences, all candidates of one Jacobian replayed in one
compiled call per experiment (:class:`impact_env.ident.model.Model`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from impact_env.ident.experiments import Experiment
from impact_env.ident.model import BOUND, INDEX, NAMES, PARAMS, SENSOR_CHANNELS, STAGE, Model

IDENTIFIED_REL = 0.1  # a parameter with a larger relative standard uncertainty is not identified
FIX_COST = 5.0  # reduced chi-squares a fit may lose when a parameter is fixed at its base value
FD_STEP = 1e-5  # forward-difference step in log-ratio (a relative 1e-5; truncation error about as small)
# a contact's force rises as b v d^0.25 at its onset (the damped pad, Tsuji): a reading taken just
# after an onset is not differentiable in the onset's time, and its derivative can be any size.
# Those readings (ONSET_MASK ticks around each onset seen in the drops' contact force) are left
# out of the fit: a few samples per contact, so that the Jacobian and the uncertainties hold
ONSET_MASK = (-3, 2)
MAX_DELAY = 20  # ticks of delay looked for (2 ms at 10 kHz)
FAILED_RESIDUAL = 1e3  # per sample, for a candidate whose plant failed


@dataclass
class SensorEstimate:
    """A channel from the quiet episodes (its unit's SI)."""

    channel: str
    offset: float
    offset_se: float
    noise_std: float
    noise_se: float
    sigma: float  # total std of a reading (noise and quantum): the residuals' weight
    n: int


@dataclass
class Fit:
    """What :func:`identify` found (SI units; see the module doc)."""

    base_toml: str
    sensors: dict[str, SensorEstimate]
    x: np.ndarray  # log-ratios of PARAMS to the base's
    cov: np.ndarray  # their covariance (0 rows/cols for parameters not identified)
    identified: np.ndarray  # bool per parameter
    fixed: dict[str, str]  # parameters not identified -> "base" (kept at the base value) or "fitted"
    k_act: int
    k_sens: int
    delay_cost: dict[str, dict[int, float]]  # cost at the delays tried, per stage
    chi2_red: float
    residual_rms: dict[str, dict[str, float]]  # kind -> channel -> RMS residual (channel's unit)
    n_samples: int
    logs: list[str]
    stages: list[dict] = field(default_factory=list)
    wall_s: float = 0.0
    model: Model | None = None

    def value(self, name: str) -> float:
        assert self.model is not None
        return float(self.model.values(self.x)[INDEX[name]])

    def rel_sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def correlations(self) -> np.ndarray:
        s = self.rel_sigma()
        with np.errstate(invalid="ignore", divide="ignore"):
            r = self.cov / np.outer(s, s)
        return np.where(np.outer(s, s) > 0, r, 0.0)


# -- stage 1: the sensors ----------------------------------------------------------------------------
def sensor_stage(exps: list[Experiment]) -> dict[str, SensorEstimate]:
    quiet = [e for e in exps if e.kind == "quiet"]
    sens = quiet[0].scene.effects.sensors
    out = {}
    for c, name in enumerate(SENSOR_CHANNELS):
        ch = getattr(sens, name)
        if not ch.enabled:
            continue
        y = np.concatenate([e.readings[e.usable, c] for e in quiet])
        n = len(y)
        mean = float(np.mean(y))
        s = float(np.std(y, ddof=1))
        q = ch.quantum
        noise = math.sqrt(max(s * s - q * q / 12.0, 0.0))
        out[name] = SensorEstimate(name, mean, s / math.sqrt(n), noise, s / math.sqrt(2.0 * (n - 1)),
                                   max(s, q / math.sqrt(12.0), 1e-300), n)
    return out


# -- the least-squares problem ------------------------------------------------------------------------
class Problem:
    """Weighted residuals of experiments ``exps`` for the free parameters ``free`` (indices into
    PARAMS), the others at ``x_fixed``, with delays (k_act, k_sens)."""

    def __init__(self, model: Model, exps: list[Experiment], sigma: dict[str, float], free, x_fixed,
                 k_act: int = 0, k_sens: int = 0):
        self.model, self.exps = model, exps
        self.free = np.asarray(free, dtype=np.int64)
        self.x_fixed = np.array(x_fixed, dtype=float)
        self.k_act, self.k_sens = k_act, k_sens
        self.channels = [(c, name, sigma[name]) for c, name in enumerate(SENSOR_CHANNELS) if name in sigma]
        self._cache: tuple[bytes, np.ndarray] | None = None
        self.evaluations = 0

    def full(self, xf: np.ndarray) -> np.ndarray:
        x = self.x_fixed.copy()
        x[self.free] = xf
        return x

    def residuals_many(self, X: np.ndarray) -> np.ndarray:
        """float64[K, N]: the weighted residuals of K full parameter vectors."""
        parts = []
        for e in self.exps:
            R = self.model.simulate(e, X, self.k_act, self.k_sens)
            m = e.usable if e.fit_mask is None else e.fit_mask
            for c, _name, s in self.channels:
                d = (e.readings[None, m, c] - R[:, m, c]) / s
                parts.append(np.where(np.isfinite(d), d, FAILED_RESIDUAL))
        self.evaluations += X.shape[0]
        return np.concatenate(parts, axis=1)

    def fun(self, xf: np.ndarray) -> np.ndarray:
        key = np.asarray(xf, dtype=float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        r = self.residuals_many(self.full(xf)[None, :])[0]
        self._cache = (key, r)
        return r

    def jac(self, xf: np.ndarray) -> np.ndarray:
        r0 = self.fun(xf)
        base = self.full(xf)
        X = np.repeat(base[None, :], len(self.free), axis=0)
        for j, k in enumerate(self.free):
            X[j, k] += FD_STEP
        R = self.residuals_many(X)
        return ((R - r0[None, :]) / FD_STEP).T

    def cost(self, xf: np.ndarray) -> float:
        r = self.fun(xf)
        return 0.5 * float(r @ r)


def bounds(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Log-ratio bounds of every parameter: a factor 4 from the base value, the restitution at
    most 1 (a pad gives back no more energy than it took)."""
    lo, hi = np.full(len(PARAMS), -BOUND), np.full(len(PARAMS), BOUND)
    j = INDEX["restitution"]
    hi[j] = min(hi[j], -math.log(model.theta0[j]))
    return lo, hi


def _solve(problem: Problem, x0: np.ndarray, max_nfev: int = 40) -> tuple[np.ndarray, float]:
    lo, hi = bounds(problem.model)
    lo, hi = lo[problem.free], hi[problem.free]
    span = hi - lo
    xf0 = np.clip(x0[problem.free], lo + 1e-9 * span, hi - 1e-9 * span)
    res = least_squares(problem.fun, xf0, jac=problem.jac, bounds=(lo, hi), method="trf",
                        x_scale=1.0, max_nfev=max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-10)
    return problem.full(res.x), float(res.cost)


def _best_delay(make, x0: np.ndarray, k0: int, quick_nfev: int = 6,
                k_max: int = MAX_DELAY) -> tuple[np.ndarray, int, dict[int, float]]:
    """The whole-tick delay in 0 .. ``k_max`` near ``k0`` whose refit costs least (``make(k)``:
    the problem at delay k); walks downhill one tick at a time."""
    costs: dict[int, float] = {}
    xs: dict[int, np.ndarray] = {}

    def at(k: int, nfev: int) -> float:
        if k not in costs:
            xs[k], costs[k] = _solve(make(k), x0 if not xs else xs[min(xs, key=lambda j: costs[j])], nfev)
        return costs[k]

    k = max(0, min(k0, k_max))
    at(k, 40)
    while True:
        nbrs = [j for j in (k - 1, k + 1) if 0 <= j <= k_max]
        for j in nbrs:
            at(j, quick_nfev)
        best = min(costs, key=lambda j: costs[j])
        if best == k:
            break
        k = best
        xs[k], costs[k] = _solve(make(k), xs[k], 40)
    return xs[k], k, costs


# -- stage 2 and 3: first guesses -----------------------------------------------------------------------
def _xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """float64[max_lag + 1]: the mean product of ``a`` with ``b`` delayed by 0 .. max_lag ticks."""
    return np.array([float(np.dot(a[k:], b[:len(a) - k])) / max(len(a) - k, 1) for k in range(max_lag + 1)])


def _contacts(phi: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """(first, last + 1) tick ranges where the contact force exceeds ``threshold``."""
    on = phi > threshold
    edges = np.flatnonzero(np.diff(on.astype(np.int8)))
    out: list[tuple[int, int]] = []
    start: int | None = 0 if on[0] else None
    for e in edges:
        i = int(e)
        if on[i + 1]:
            start = i + 1
        elif start is not None:
            out.append((start, i + 1))
            start = None
    if start is not None:
        out.append((start, len(on)))
    return out


def mask_onsets(e: Experiment, sensors: dict[str, SensorEstimate], top_mass: float) -> int:
    """Leave the readings around each contact onset of drop ``e`` out of the fit (ONSET_MASK);
    returns the number of onsets seen (the measured contact force ``m2' a2 + T`` over 6 of its
    standard deviations)."""
    y = np.where(np.isfinite(e.readings[:, :2]), e.readings[:, :2], 0.0)
    phi = (y[:, 1] - sensors["force"].offset) + top_mass * (y[:, 0] - sensors["accelerometer"].offset)
    sig = math.hypot(sensors["force"].sigma, top_mass * sensors["accelerometer"].sigma)
    mask = e.usable.copy()
    con = _contacts(phi, 6 * sig)
    for i0, _i1 in con:
        mask[max(i0 + ONSET_MASK[0], 0):i0 + ONSET_MASK[1]] = False
    e.fit_mask = mask
    return len(con)


def drop_guess(model: Model, x: np.ndarray, drops: list[Experiment],
               sensors: dict[str, SensorEstimate]) -> dict:
    """First guesses of m1, c and the restitution from the drops' timing and impulse (thesis
    eq 4.5 and Hertz's contact time), and of the sensor delay from the first contact's onset."""
    sc = model.scene(x)
    p = sc.plant
    top = model.values(x)[INDEX["top_mass"]]
    g = p.gravity
    a_off = sensors["accelerometer"].offset
    v_in = sc.impact_speed
    rate = sc.control_rate
    # the model's own first onset (no sensor delay): the touch, as the candidate has it
    R = model.simulate(drops[0], x[None, :])[0]
    sig_phi = math.hypot(sensors["force"].sigma, top * sensors["accelerometer"].sigma)
    out: dict[str, list[float]] = {"m1": [], "c": [], "restitution": [], "k_sens": [], "m2": []}
    phi_model = (R[:, 1] - sensors["force"].offset) + top * (R[:, 0] - sensors["accelerometer"].offset)
    model_on = _contacts(phi_model, 6 * sig_phi)
    for e in drops:
        y = np.where(np.isfinite(e.readings[:, :2]), e.readings[:, :2], 0.0)
        phi = (y[:, 1] - sensors["force"].offset) + top * (y[:, 0] - sensors["accelerometer"].offset)
        con = _contacts(phi, 6 * sig_phi)
        con = [c for c in con if c[1] - c[0] >= 3]  # noise spikes are a tick or two
        if not con:
            continue
        i0, i1 = con[0]
        if model_on:
            out["k_sens"].append(i0 - model_on[0][0])
        impulse = float(np.sum(phi[i0:i1])) / rate
        tc = (i1 - i0) / rate
        # body 2 takes the impulse against its mass (the suspension is slow beside a contact)
        dv2 = float(np.sum(y[i0:i1, 0] - a_off)) / rate
        m2 = impulse / dv2 if dv2 > 0 else p.m2
        out["m2"].append(m2)
        if len(con) > 1:
            v1_out = 0.5 * g * (con[1][0] - i1) / rate  # body 1's rebound, from its flight (eq 4.5)
            m1 = impulse / (v_in + v1_out)
            out["m1"].append(m1)
            # the pad's restitution is of the relative speed: body 2 leaves at impulse / m2
            out["restitution"].append((v1_out + impulse / m2) / v_in)
            meff = m1 * m2 / (m1 + m2)
            out["c"].append(5 * meff / (4 * v_in**2) * (2.9432 / (v_in * tc)) ** 2.5)
    return {k: float(np.median(v)) for k, v in out.items() if v}


# -- the whole fit -------------------------------------------------------------------------------------
def identify(exps: list[Experiment], base=None, progress=None) -> Fit:
    """The staged fit (module doc) of ``exps`` (:func:`impact_env.ident.experiments.load`) on
    ``base`` (a Scene; default: the scene the logs were recorded with)."""
    t0 = time.perf_counter()
    say = progress or (lambda *_: None)
    base = base if base is not None else exps[0].scene
    sensors = sensor_stage(exps)
    sigma = {k: v.sigma for k, v in sensors.items()}
    model = Model(base, {k: v.offset for k, v in sensors.items()})
    shaker = [e for e in exps if e.kind == "shaker"]
    drops = [e for e in exps if e.kind == "ident_drop"]
    P = len(PARAMS)
    x = np.zeros(P)
    stages: list[dict] = []
    delay_cost: dict[str, dict[int, float]] = {}

    # 2: the shaker; the total delay first guessed from the accelerometer's lag behind the model's
    say("shaker stage")
    # (differenced: the lag is sharpest in the high band, where a delay is a large phase)
    corr = np.zeros(MAX_DELAY + 1)
    for e in shaker:
        R = model.simulate(e, x[None, :])[0]
        a_meas = np.diff(np.where(e.usable, e.readings[:, 0], R[:, 0]))
        corr += _xcorr(a_meas, np.diff(R[:, 0]), MAX_DELAY)
    k0 = int(np.argmax(corr))
    x, k_tot, delay_cost["shaker"] = _best_delay(
        lambda k: Problem(model, shaker, sigma, STAGE["shaker"], x, k_act=k), x, k0)
    stages.append({"stage": "shaker", "delay_ticks": k_tot, "cost": delay_cost["shaker"][k_tot]})

    # 3: the drops, from their own timing
    say("drop stage")
    guess = drop_guess(model, x, drops, sensors)
    lo, hi = bounds(model)
    if "m2" in guess and guess["m2"] > 0:  # the ratios stay: drive, k2 and c2 move with m2
        x[INDEX["m2"]] = float(np.clip(math.log(guess["m2"] / model.theta0[INDEX["m2"]]),
                                       0.9 * lo[0], 0.9 * hi[0]))
    for name in ("m1", "c", "restitution"):
        j = INDEX[name]
        if name in guess and guess[name] > 0:
            x[j] = float(np.clip(math.log(guess[name] / model.theta0[j]), 0.9 * lo[j], hi[j] - 0.01))
    for e in drops:
        mask_onsets(e, sensors, model.values(x)[INDEX["top_mass"]])
    # the sensor delay is part of the total the shaker stage found: 0 .. k_tot
    ks0 = int(max(0, min(round(guess.get("k_sens", 0.0)), k_tot)))
    x, k_sens, delay_cost["drop"] = _best_delay(
        lambda k: Problem(model, drops, sigma, STAGE["drop"], x, k_act=k_tot - k, k_sens=k), x, ks0,
        k_max=k_tot)
    k_act = max(k_tot - k_sens, 0)
    stages.append({"stage": "drop", "guess": guess, "delay_ticks": k_sens,
                   "cost": delay_cost["drop"][k_sens]})

    # 4: joint, then without the parameters the logs do not determine, one at a time (the
    # least determined first): fixed at the base value when the fit without it is as good (a
    # cost rise within FIX_COST reduced chi-squares), else where the joint fit left it (its
    # partner then carries the base's error: e.g. the band's upper edge and the coil pole, which
    # enter the force almost only through their summed lag)
    say("joint stage")
    every = [e for e in exps if e.kind in ("shaker", "ident_drop")]
    free = np.arange(P)
    fixed: dict[str, str] = {}
    prob = Problem(model, every, sigma, free, x, k_act, k_sens)
    x, cost = _solve(prob, x, 30)
    cov_f, s2, N = _covariance(prob, x)
    stages.append({"stage": "joint", "cost": cost, "chi2_red": s2})
    while True:
        rel = np.sqrt(np.maximum(np.diag(cov_f), 0.0))
        w = int(np.argmax(rel))
        if rel[w] <= IDENTIFIED_REL:
            break
        j = int(free[w])
        rest = free[free != j]
        xb = x.copy()
        xb[j] = 0.0
        xb, cost_b = _solve(Problem(model, every, sigma, rest, xb, k_act, k_sens), xb, 30)
        if cost_b - cost <= FIX_COST * s2:
            x, cost, fixed[NAMES[j]] = xb, cost_b, "base"
        else:
            x, cost = _solve(Problem(model, every, sigma, rest, x, k_act, k_sens), x, 30)
            fixed[NAMES[j]] = "fitted"
        free = rest
        prob = Problem(model, every, sigma, free, x, k_act, k_sens)
        cov_f, s2, N = _covariance(prob, x)
        stages.append({"stage": "joint", "fixed": NAMES[j], "at": fixed[NAMES[j]], "rel_sigma": float(rel[w]),
                       "cost": cost, "chi2_red": s2})
    cov = np.zeros((P, P))
    cov[np.ix_(free, free)] = cov_f
    identified = np.zeros(P, dtype=bool)
    identified[free] = True
    fit = Fit(base_toml=base.to_toml(), sensors=sensors, x=x, cov=cov, identified=identified, fixed=fixed,
              k_act=k_act,
              k_sens=k_sens, delay_cost=delay_cost, chi2_red=s2,
              residual_rms=_residual_rms(model, exps, x, k_act, k_sens), n_samples=N,
              logs=[e.path for e in exps], stages=stages, wall_s=time.perf_counter() - t0, model=model)
    return fit


def _covariance(prob: Problem, x: np.ndarray) -> tuple[np.ndarray, float, int]:
    """(covariance s^2 (J^T J)^-1 of the free parameters, reduced chi-square s^2, residuals)."""
    J = prob.jac(x[prob.free])
    r = prob.fun(x[prob.free])
    N = len(r)
    s2 = float(r @ r) / max(N - len(prob.free), 1)
    return s2 * np.linalg.pinv(J.T @ J, rcond=1e-13), s2, N


def _residual_rms(model: Model, exps: list[Experiment], x: np.ndarray, k_act: int, k_sens: int) -> dict:
    out: dict[str, dict[str, list[np.ndarray]]] = {}
    for e in exps:
        if e.kind == "quiet":
            continue
        R = model.simulate(e, x[None, :], k_act, k_sens)[0]
        for c, name in enumerate(SENSOR_CHANNELS):
            d = e.readings[e.usable, c] - R[e.usable, c]
            out.setdefault(e.kind, {}).setdefault(name, []).append(d[np.isfinite(d)])
    return {k: {c: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for c, v in d.items()}
            for k, d in out.items()}
