"""``oracle``: the best force-command sequence found for each drop, the yardstick of ``compare``.

What it is.  For a given drop the rig is deterministic: sensor noise changes what a controller
reads, never how the bodies move.  The oracle is therefore a *privileged, per-drop, open-loop*
policy: before the episode it is told the drop's seed, optimises the whole command sequence
``u[0..n_steps-1]`` (in [-1, 1], 1 = ``effects.command_scale`` N up, the env's action space, so
the scene's force limit applies as it does to every policy) to minimise the episode's
``energy_integral_ms`` (:mod:`impact_env.eval.rollout`: the time integral of body 1's
catch-energy ratio), and then replays it.  Its row is an **upper bound on the best energy
integral any policy can reach on those drops** (every policy's commands form one open-loop
sequence), found by a local optimiser: not a proof of optimality.  The figure that says how far
the bound may still be from the true optimum is the budget study (``scripts/oracle_budget.py``,
below): how much the result still improves with more generations.

Warm starts and the guarantee.  The optimiser starts from command sequences known to be good on
the drop: the classic laws' (``pd-penetration``, ``thesis-rig``, ``passive``, each rolled out on
the drop, where the scene has the channels they need; recorded commands given under the same
name are used instead) are the bases of its residual.  In ``compare`` the commands of every
other policy of the comparison are given too (``warm_starts`` of
:func:`impact_env.eval.rollout.rollout`); they join the final choice, which is made on
full-horizon rollouts of the scene itself (sensors included, the code path of the table): the
best of the optimiser's finalists and of *every warm start as recorded*.  Replaying a recorded
sequence reproduces its episode bitwise, so no policy of the comparison can beat the oracle's
energy integral on any drop; one that did would show a bug.  Every registered classic law
(``mpc-state`` and ``mpc`` among them) is rolled out on the drop and joins the final choice too,
whether or not the comparison holds it, so that the yardstick does not depend on which policies
stand beside it (without them, a comparison without ``mpc-state`` would measure its agents
against an oracle 5 % weaker on ``rig``: 2.90 against 2.76 ms on drops 1000-1099); the cached
oracle of the benchmark (:mod:`impact_env.eval.oracle_cache`) is given the same laws.  Only the classic
laws serve as bases, so that the yardstick does not move with the comparison it stands in: the residual is
smooth and cannot remove a base's chatter, and the PPO agent's commands, better than
``pd-penetration``'s on the optimiser's objective at ``c = 0``, made a worse base (median 2.90
against 2.82 ms on drops 1000-1019 of ``rig``, see README "The oracle").

Parameterisation.  A residual on the best *base* ``w``, the classic law whose sequence scores
best on the optimiser's own objective (``pd-penetration`` on ``rig``)::

    u_c(t_j) = clip(w_j + sum_k c_k B_k(t_j), -1, 1)     for t_j < T_w  (the window)
    u_c(t_j) = u_c(t_{n_w - 1})                           after it (the last command held)

with ``B_k`` the ``basis`` clamped cubic B-splines on knots that start ``LEAD_S`` (1 ms) before
the first touch, with a first interval of ``first_knot`` s growing geometrically up to the
window's end ``T_w = t_touch + window``: fine where the first impact happens (about 3 ms on the
rig), coarse where the bodies are settling.  ``c = 0`` is the base inside the window.  CMA-ES
(the ``cma`` package) searches ``c`` from 0 with step ``sigma`` (command units); each generation
is one batched simulator call (its ``popsize`` candidates are the envs of one batch, all
started from the drop's seed).

Why a window and a held tail.  A candidate costs one simulation, and almost all of the integral
is made in the first tens of ms (the free fall to the pad, the first impact, the first
rebound), so candidates are simulated only up to ``T_w``; the rest of the horizon is
estimated.  After ``T_w`` the command is held, not handed back to the warm start: the warm
start's later commands answer *its* bounces and throw a body that the optimised commands have
already caught (in trials with ``pd-penetration``'s tail, sequences that were good up to
``T_w`` ended far worse than ``pd-penetration`` itself), and a step to 0 would kick body 2
through the shaker.  The
estimate of the tail, ``(r + (m1/M) E_s / (2 E_0)) tau (1 - exp(-(H - T_w) / tau))``, is the
energy left at ``T_w`` decaying with the suspension mode: ``r`` is body 1's catch-energy ratio
at ``T_w``, ``E_s = m1 v1^2/2 + m2 v2^2/2 + k2 (x2 - x_eq)^2 / 2`` the energy of the suspension
mode about its equilibrium under the held force ``F`` with body 1 on the pad,
``x_eq = (m1 g - F) / k2`` (x down, F up), of which body 1 carries ``m1 / M`` of the kinetic
half, and ``tau = M / c2`` (M = m1 + m2) the decay time of that energy (55 ms on rig).  Without
it the optimiser leaves body 2 displaced, or holds a force that displaces it, at ``T_w``: the
window rewards that and the full horizon punishes it (in trials, a calm state at ``T_w`` with
a held pull of about 60 N launched body 1 once the window was over).  The held force then fades
through the shaker's 5 Hz high-pass (32 ms), which moves the equilibrium back slowly against the
16 Hz suspension mode; the estimate leaves that out.  It is a heuristic; the choice among
finalists is made on the full horizon, so it can only cost quality, never validity.

Cost model.  Candidates run on the rig's physics only: the drop's scene (its randomised values
drawn from the drop's seed exactly as the simulator's reset draws them, see the seed policy of
:mod:`impact_env.scene.randomize`) with the sensor side (``sensors``, ``filters``,
``sensor_delay``, ``detector``) switched off: those stages only compute readings, so the bodies
move exactly as in the full scene (bitwise on a fixed scene; on a randomised scene the pad
damping of a drawn restitution comes from the simulator's table, equal to the exact solve that
the fixed scene uses to about 1e-10, so the two agree to that order), at about 80 % of the
cost.  All Simulator use is in :class:`_Rig`.

Budget (defaults; ``compare --policies ...,oracle:generations=200,popsize=12`` changes them):
``generations`` = 100, ``popsize`` = 12, ``basis`` = 12, ``window`` = 20 ms after the first
touch, ``first_knot`` = 0.25 ms, ``sigma`` = 0.3: 1203 simulations of 21 ms, about 3 s of CPU
per drop.  Measured adequacy on drops 1000-1009 of ``rig`` (``python scripts/oracle_budget.py
--drops 10 --generations 25,50,100,200,300``; median energy integral, best warm start
``pd-penetration`` 7.59 ms): 3.13 ms after 25 generations, 3.04 after 50, 2.83 after 100, 2.77
after 200, 2.75 after 300; ten times the default budget with a finer basis (16 splines, 1000
generations, 33 s per drop, drops 1000-1002) reaches 2.73 ms, so the default stands about 4 %
above the best this search has found.  A window of 10 ms is too short for the tail estimate
(the full-horizon result does not improve as the window objective does), 50 ms costs more than
twice as much per generation and converges more slowly; 8 splines stall near 2.92 ms, 16
converge more slowly (README, "The oracle", has the runs).

Randomness: CMA-ES draws from ``numpy.random.default_rng([seed, CMA_STREAM])`` (one stream per
drop), never from numpy's global generator: one seed gives one result, whatever ran before.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding

from impact_env._borrow import borrow
from impact_env._jit import jit
from impact_env.config import ConfigError, check_range
from impact_env.effects.registry import READINGS_ONLY
from impact_env.eval.rollout import rollout
from impact_env.hardware.stage import INFO_F_APPLIED
from impact_env.plant.energy import catch_energy_at
from impact_env.plant.layout import PARAM, STATE
from impact_env.policy.registry import make_policy
from impact_env.scene import Scene, load_scene
from impact_env.sim.simulator import Simulator
from impact_env.sim.step import sim_step

SENSOR_SIDE = READINGS_ONLY  # effects that only compute readings (impact_env.effects.registry)
WARM_POLICIES = ("pd-penetration", "thesis-rig", "passive")  # the classic laws the oracle rolls out itself
LEAD_S = 1.0e-3  # s: the basis starts this long before the first touch (the rig's pre-contact time)
CMA_STREAM = 0x0AC1E  # second word of the CMA-ES generator's seed: a stream apart from the drop's own


# -- parameters ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OracleParam:
    """One budget parameter: default, unit, meaning and allowed range (``compare --list``)."""

    default: object
    unit: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    integer: bool = False
    choices: tuple[str, ...] = ()

    def check(self, key: str, value):
        where = f"oracle parameter {key}"
        if self.choices:
            if value not in self.choices:
                raise ConfigError(f"{where} = {value!r} is not one of {', '.join(self.choices)}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        value = float(value)
        check_range(where, value, self.unit, self.lo, self.hi)
        if self.integer:
            if value != int(value):
                raise ConfigError(f"{where} = {value!r} must be a whole number (>= {self.lo:g})")
            return int(value)
        return value


PARAMS: dict[str, OracleParam] = {
    "generations": OracleParam(100, "", "CMA-ES generations per drop (one batched simulation each)",
                               lo=1, hi=100000, integer=True),
    "popsize": OracleParam(12, "", "candidates per generation (envs of one batch)", lo=2, hi=4096,
                           integer=True),
    "basis": OracleParam(12, "", "cubic B-spline coefficients of the residual command", lo=4, hi=1000,
                         integer=True),
    "window": OracleParam(0.02, "s", "optimised span after the first touch (the command is held after it)",
                          lo=1e-6, hi=1e4),
    "first_knot": OracleParam(2.5e-4, "s", "first knot interval (intervals grow geometrically to the "
                              "window's end)", lo=1e-7, hi=1e4),
    "sigma": OracleParam(0.3, "", "CMA-ES initial step, in command units (1 = command_scale N)",
                         lo=1e-6, hi=10.0),
    "warm": OracleParam("classic", "", "bases of the residual: 'classic' = pd-penetration, thesis-rig and "
                        "passive (rolled out by the oracle unless given); 'given' = the given warm starts "
                        "and passive.  Every given warm start joins the final choice either way",
                        choices=("classic", "given")),
}


@dataclass(frozen=True)
class Budget:
    """The optimiser's budget and parameterisation (see :data:`PARAMS` for units and ranges)."""

    generations: int = 100
    popsize: int = 12
    basis: int = 12
    window: float = 0.02
    first_knot: float = 2.5e-4
    sigma: float = 0.3

    @classmethod
    def from_params(cls, **params) -> Budget:
        unknown = sorted(set(params) - set(PARAMS))
        if unknown:
            raise ConfigError(f"unknown parameter(s) {', '.join(unknown)} for policy 'oracle' "
                              f"(valid: {', '.join(PARAMS)})")
        vals = {k: PARAMS[k].check(k, v) for k, v in params.items()}
        vals.pop("warm", None)
        return cls(**vals)


# -- the physics-only cost model -------------------------------------------------------------------
def drop_generator(seed: int) -> np.random.Generator:
    """The Generator an env seeded ``seed`` gets (``gymnasium.utils.seeding.np_random``)."""
    return seeding.np_random(int(seed))[0]


def physics_scene(scene: Scene, seed: int) -> Scene:
    """The drop of ``scene`` seeded ``seed`` as a fixed scene without the sensor side.

    A randomised scene's values are drawn from ``drop_generator(seed)`` with the call the
    simulator's reset makes first (:meth:`Scene.draw`), so they are the drop's values; the
    effects that only compute readings (:data:`SENSOR_SIDE`) are switched off."""
    fixed = scene.with_draws(scene.draw(drop_generator(seed))) if scene.randomized else scene
    active = [e for e in fixed.effects.active if e not in SENSOR_SIDE]
    if len(active) == len(fixed.effects.active):
        return fixed
    return fixed.with_overrides({"effects.active": active})


class _Rig:
    """The adapter: the only code here that uses :class:`impact_env.sim.simulator.Simulator`.

    ``run(seed, U)`` simulates the commands ``U`` (float64[T, N], one column per env, every env
    reset with the Generator of ``seed``) and returns the energy integral over the T steps (ms,
    as :mod:`impact_env.eval.rollout` sums it: the catch-energy ratio after each step times the
    period) and the end state: ``ratio`` (float64[N]), ``Y`` (float64[N, 4]: x1, v1, x2, v2),
    ``force`` (N, on body 2 over the last step, up positive), ``impact_energy`` (J), ``diverged``
    (bool[N])."""

    def __init__(self, scene: Scene, n: int):
        self.sim = Simulator(scene, n)
        self.n = n
        self.period = scene.control_period

    def run(self, seed: int, U: np.ndarray):
        sim = self.sim
        sim.reset([drop_generator(seed) for _ in range(self.n)])
        e0 = np.array(sim.impact_energy, dtype=np.float64)
        acc = np.zeros(self.n)
        # the population's steps in compiled chunks (a chunk's noise drawn first), not one Python
        # step at a time: the same numbers as sim.step per step (tests/test_oracle.py), since an env
        # touches only its own rows and the noise is the same stream drawn in pieces
        U = np.ascontiguousarray(U, dtype=np.float64)
        hold = sim.hold
        chunk = max(1, sim.hw.noise_block // hold)
        for k in range(0, U.shape[0], chunk):
            k1 = min(U.shape[0], k + chunk)
            sim.hw.refill_noise(hold * (k1 - k))
            _replay_steps(k, k1, U, sim.params, sim.state, e0, acc)
        ratio = sim.catch_energy() / e0
        return acc * self.period * 1e3, {"ratio": ratio, "Y": np.array(sim.Y[:, :4]), "impact_energy": e0,
                                          "force": np.array(sim.info[:, INFO_F_APPLIED]),
                                          "diverged": np.asarray(sim.diverged(), dtype=bool)}

    def touch_time(self, seed: int) -> float:
        """s from the episode start to the first touch (the same for every env of the drop)."""
        self.sim.reset([drop_generator(seed) for _ in range(self.n)])
        return float(np.asarray(self.sim.t_touch)[0])


@jit(nogil=True)
def _replay_steps(k0, k1, commands, p, s, e0, acc):
    """Steps k0 .. k1 - 1 of the commands ``commands[k, i]`` on every env i of the simulator
    (SimParams ``p``, SimState ``s``; its noise for them drawn), adding each step's catch-energy ratio (its
    catch energy over ``e0[i]``) to ``acc[i]``."""
    commands, p, s, e0, acc = borrow(commands), borrow(p), borrow(s), borrow(e0), borrow(acc)
    plant_states = s.hw.plant.y
    plant_params = p.hw.plant.p
    actions = np.zeros(plant_states.shape[0])  # the vector env's step on one env at a time
    active = np.ones(plant_states.shape[0], dtype=np.bool_)
    for i in range(plant_states.shape[0]):
        for k in range(k0, k1):
            actions[i] = commands[k, i]
            sim_step(i, i + 1, actions, active, p, s)
            acc[i] += catch_energy_at(plant_states[i, STATE.x1], plant_states[i, STATE.v1],
                                      plant_states[i, STATE.x2], plant_params[i, PARAM.m1],
                                      plant_params[i, PARAM.c], plant_params[i, PARAM.g]) / e0[i]


# -- parameterisation ---------------------------------------------------------------------------------
def knots(t0: float, t_end: float, n_basis: int, first: float) -> np.ndarray:
    """Interior knots of ``n_basis`` clamped cubic B-splines on [t0, t_end] (s): ``n_basis - 3``
    intervals, the first ``first`` s long, growing by a common ratio (uniform if ``first`` is not
    shorter than the uniform interval)."""
    n = n_basis - 3
    span = t_end - t0
    if not span > 0:
        raise ValueError(f"empty basis span [{t0}, {t_end}] s")
    if first * n >= span or n == 1:
        return t0 + span * np.arange(n + 1) / n
    lo, hi = 1.0, 2.0
    while first * (hi ** n - 1.0) / (hi - 1.0) < span:
        hi *= 2.0
    for _ in range(200):  # bisection on the ratio r: first (r^n - 1) / (r - 1) = span
        r = 0.5 * (lo + hi)
        if r == lo or r == hi:
            break
        if first * (r ** n - 1.0) / (r - 1.0) > span:
            hi = r
        else:
            lo = r
    r = 0.5 * (lo + hi)
    h = first * r ** np.arange(n)
    out = t0 + np.concatenate([[0.0], np.cumsum(h)])
    out[-1] = t_end
    return out


def basis_matrix(period: float, n_window: int, t0: float, t_end: float, n_basis: int,
                 first: float) -> np.ndarray:
    """float64[n_window, n_basis]: the B-splines at the start of each control period ``j T``
    (zero before ``t0``)."""
    from scipy.interpolate import BSpline

    kn = knots(t0, t_end, n_basis, first)
    t = np.concatenate([[kn[0]] * 3, kn, [kn[-1]] * 3])
    tj = np.arange(n_window) * period
    inside = (tj >= kn[0]) & (tj < kn[-1])
    B = np.zeros((n_window, n_basis))
    if inside.any():
        B[inside] = BSpline.design_matrix(tj[inside], t, 3).toarray()
    return B


def candidates(base: np.ndarray, B: np.ndarray, C: np.ndarray, n_steps: int) -> np.ndarray:
    """float64[n_steps, P]: the sequences of the coefficient rows ``C`` (float64[P, K]) on the
    warm start ``base`` (float64[n_steps]): residual inside the window, last command held."""
    n_w = B.shape[0]
    U = np.empty((n_steps, C.shape[0]))
    U[:n_w] = np.clip(base[:n_w, None] + B @ C.T, -1.0, 1.0)
    U[n_w:] = U[n_w - 1]
    return U


def tail_estimate(end: dict, plant, horizon_left: float) -> np.ndarray:
    """The energy integral (ms) expected after the window (module doc), from the end state."""
    if horizon_left <= 0:
        return np.zeros(len(end["ratio"]))
    m1, m2, g = plant.m1, plant.m2, plant.gravity
    k2, c2 = plant.suspension_stiffness, plant.suspension_damping
    M = m1 + m2
    Y = end["Y"]
    x_rest = (m1 * g - end["force"]) / k2 if k2 > 0 else Y[:, 2]
    e_s = 0.5 * m1 * Y[:, 1] ** 2 + 0.5 * m2 * Y[:, 3] ** 2 + 0.5 * k2 * (Y[:, 2] - x_rest) ** 2
    tau = M / c2 if c2 > 0 else math.inf
    span = horizon_left if math.isinf(tau) else tau * -math.expm1(-horizon_left / tau)
    return (end["ratio"] + 0.5 * (m1 / M) * e_s / end["impact_energy"]) * span * 1e3


# -- one drop ------------------------------------------------------------------------------------------
def window(phys: Scene, seed: int, n_steps: int, budget: Budget) -> tuple[float, int]:
    """``(t0, n_w)``: where the basis starts (s) and the window's length in control steps, for the
    drop's physics scene; ConfigError if that span holds fewer than 5 control periods."""
    period = phys.control_period
    t_touch = _Rig(phys, 1).touch_time(seed)
    t0 = max(0.0, t_touch - LEAD_S)
    n_w = min(n_steps, max(1, int(math.ceil((t_touch + budget.window) / period - 1e-9))))
    if n_w * period < t0 + 5 * period - 1e-12:
        raise ConfigError(f"oracle: the optimised span {t0:g} .. {n_w * period:g} s holds fewer than 5 "
                          f"control periods of {period:g} s (window = {budget.window:g} s after the first "
                          f"touch at {t_touch:g} s, horizon {n_steps * period:g} s): lengthen the window or "
                          "the horizon")
    return t0, n_w


@dataclass
class DropSearch:
    """The optimiser's outcome on one drop, before the full-horizon choice."""

    finalists: list  # float64[n_steps] sequences: best-ever, CMA mean, best of the last generation
    base: str  # the warm start the residual is on
    objective: float  # best windowed objective (ms)
    evaluations: int
    seconds: float  # wall time
    cpu_seconds: float  # this process's CPU time (what a shared machine does not inflate)
    history: np.ndarray  # best windowed objective after each generation
    checkpoints: dict  # generation -> (best-ever sequence, cpu seconds so far) (for the budget study)


def search_drop(scene: Scene, seed: int, warm: dict[str, np.ndarray], n_steps: int, budget: Budget,
                checkpoints: tuple[int, ...] = ()) -> DropSearch:
    """CMA-ES on one drop (module doc): ``warm`` maps names to float64[n_steps] sequences."""
    import cma

    t_wall, t_cpu = time.perf_counter(), time.process_time()
    phys = physics_scene(scene, seed)
    period = scene.control_period
    t0, n_w = window(phys, seed, n_steps, budget)
    t_end = n_w * period
    B = basis_matrix(period, n_w, t0, t_end, budget.basis, budget.first_knot)
    left = (n_steps - n_w) * period

    def objective(rig, U):
        J, end = rig.run(seed, U[:n_w])
        J = J + tail_estimate(end, phys.plant, left)
        return np.where(end["diverged"] | ~np.isfinite(J), np.inf, J)

    names = list(warm)
    W = np.stack([warm[k] for k in names], axis=1)
    zero = np.zeros((1, budget.basis))
    starts = np.stack([candidates(W[:, i], B, zero, n_steps)[:, 0] for i in range(len(names))], axis=1)
    J0 = objective(_Rig(phys, len(names)), starts)
    i0 = int(np.argmin(J0))
    base = W[:, i0]

    gen = np.random.default_rng([int(seed), CMA_STREAM])
    opts = {"popsize": budget.popsize, "seed": np.nan, "randn": lambda *shape: gen.standard_normal(shape),
            "verbose": -9, "verb_disp": 0, "verb_log": 0, "maxiter": budget.generations,
            "tolfun": 0.0, "tolfunhist": 0.0, "tolx": 0.0, "tolstagnation": budget.generations + 1}
    es = cma.CMAEvolutionStrategy(np.zeros(budget.basis), budget.sigma, opts)
    rig = _Rig(phys, budget.popsize)
    best_j, best_c = float(J0[i0]), np.zeros(budget.basis)
    last_c = best_c
    history = np.full(budget.generations, np.nan)
    saved = {}
    evals = len(names)
    for g in range(budget.generations):
        X = np.asarray(es.ask())
        J = objective(rig, candidates(base, B, X, n_steps))
        evals += len(X)
        es.tell(list(X), [float(j) if np.isfinite(j) else 1e300 for j in J])
        i = int(np.argmin(J))
        last_c = X[i]
        if J[i] < best_j:
            best_j, best_c = float(J[i]), X[i].copy()
        history[g] = best_j
        if g + 1 in checkpoints:
            saved[g + 1] = (candidates(base, B, best_c[None], n_steps)[:, 0], time.process_time() - t_cpu)
        if es.stop():  # only a numerical stop is left on (the tolerances are off)
            break
    mean = np.asarray(es.mean, dtype=np.float64)
    finalists = [candidates(base, B, c[None], n_steps)[:, 0] for c in (best_c, mean, last_c)]
    return DropSearch(finalists=finalists, base=names[i0], objective=best_j, evaluations=evals,
                      seconds=time.perf_counter() - t_wall, cpu_seconds=time.process_time() - t_cpu,
                      history=history, checkpoints=saved)


# -- full-horizon rollouts of given sequences ----------------------------------------------------------
class Replay:
    """Commands replayed open loop by :func:`impact_env.eval.rollout.rollout`."""

    observation = "privileged"

    def __init__(self, commands: np.ndarray):
        self.open_loop = commands

    def prepare(self, scene, seeds, horizon, warm_starts):
        pass

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        raise RuntimeError("an open-loop replay is not asked for actions")


def replay(scene: Scene, seeds, commands: np.ndarray, horizon: float):
    """Roll out ``commands`` (float64[n_steps, N]) open loop on the drops ``seeds`` (N ints) of
    the full scene; returns the :class:`~impact_env.eval.rollout.RolloutResult`."""

    return rollout(scene, Replay(np.asarray(commands, dtype=np.float64)), list(seeds), horizon=horizon,
                   trace_rate=0.0, name="replay")


def classic_law_names() -> list[str]:
    """Every registered classic law (:data:`impact_env.policy.laws.LAW_POLICIES`): the sequences
    that join each drop's final choice, so that none beats the oracle on any drop."""
    from impact_env.policy.laws import LAW_POLICIES

    return list(LAW_POLICIES)


def classic_warm_starts(scene: Scene, seeds, horizon: float, specs=WARM_POLICIES) -> dict[str, np.ndarray]:
    """The commands the classic laws issue on the drops (name -> float64[n_steps, N]); laws the
    scene cannot run (a missing sensor channel) are left out."""

    out = {}
    for spec in specs:
        try:
            policy = make_policy(spec, scene)
        except (ConfigError, ValueError):
            continue
        r = rollout(scene, policy, list(seeds), horizon=horizon, trace_rate=0.0, name=spec,
                    record_commands=True)
        out[spec] = r.extras["commands"]
    return out


# -- the policy --------------------------------------------------------------------------------------------
class OraclePolicy:
    """The ``oracle`` compare policy (module doc).  Use through ``rollout``/``compare``, which call
    :meth:`prepare` with the episodes' seeds; then ``open_loop`` holds the commands
    (float64[n_steps, N]) and ``stats`` the per-drop figures (arrays over episodes):
    ``energy_integral_ms`` (the chosen sequence's, from a full rollout), ``best_warm_ms`` and
    ``best_warm`` (the best warm start's and its name), ``improvement_ms`` (best warm start minus
    oracle, >= 0), ``source`` ("cma" or the warm start kept), ``evaluations``, ``seconds`` (wall)
    and ``cpu_seconds`` of the optimisation per drop, ``window_objective_ms`` (the optimiser's
    best objective: window plus tail estimate)."""

    name: ClassVar[str] = "oracle"
    observation: ClassVar[str] = "privileged"
    is_oracle: ClassVar[bool] = True  # compare: run last, pass the others' commands, report gaps to it
    PARAMS: ClassVar[dict[str, OracleParam]] = PARAMS

    def __init__(self, scene, **params):
        self.scene = load_scene(scene)
        self.budget = Budget.from_params(**params)
        self.warm = PARAMS["warm"].check("warm", params.get("warm", PARAMS["warm"].default))
        try:
            import cma  # noqa: F401
        except ImportError as exc:  # pragma: no cover - cma is a declared extra
            raise ConfigError("the oracle needs the 'cma' package (pip install 'impact-env[oracle]')") \
                from exc
        self.open_loop: np.ndarray | None = None
        self.stats: dict | None = None
        self._k = 0

    def prepare(self, scene, seeds, horizon: float, warm_starts: dict[str, np.ndarray]) -> None:
        """Optimise the commands for every drop ``seeds`` (ints) over ``horizon`` s."""
        scene = load_scene(scene)
        seeds = [int(s) for s in seeds]
        period = scene.control_period
        n_steps = int(round(horizon / period))
        n = len(seeds)
        given = {}
        for key, u in warm_starts.items():
            u = np.asarray(u, dtype=np.float64)
            if u.shape != (n_steps, n):
                raise ValueError(f"warm start {key!r} has shape {u.shape}; expected ({n_steps}, {n})")
            given[key] = np.clip(np.nan_to_num(u), -1.0, 1.0)
        for seed in seeds:  # refuse a degenerate window before anything is simulated
            window(physics_scene(scene, seed), seed, n_steps, self.budget)
        own = WARM_POLICIES if self.warm == "classic" else ("passive",)
        # every classic law joins the final choice (the bases stay own's), whatever the comparison
        # holds: otherwise the yardstick's strength moves with the comparison's members
        rolled = [s for s in own if s not in given] + [s for s in classic_law_names()
                                                       if s not in given and s not in own]
        warm = {**given, **classic_warm_starts(scene, seeds, horizon, rolled)}
        bases = [k for k in warm if k in own or (self.warm == "given" and k in given)]

        searches = []
        for i, seed in enumerate(seeds):
            searches.append(search_drop(scene, seed, {k: warm[k][:, i] for k in bases}, n_steps,
                                        self.budget))
        # full-horizon choice: every drop's finalists and its warm starts as recorded, one rollout
        names = list(warm)
        cols: list = []
        owner: Any = []  # the drop of each candidate (a list, then an int array)
        label: list[str] = []
        for i, s in enumerate(searches):
            for u in s.finalists:
                cols.append(u)
                owner.append(i)
                label.append("cma")
            for k in names:
                cols.append(warm[k][:, i])
                owner.append(i)
                label.append(k)
        r = replay(scene, [seeds[i] for i in owner], np.stack(cols, axis=1), horizon)
        ei = np.where(np.isnan(r.metrics["energy_integral_ms"]), np.inf, r.metrics["energy_integral_ms"])
        owner = np.asarray(owner)
        self.open_loop = np.zeros((n_steps, n))
        keys = ("energy_integral_ms", "best_warm_ms", "improvement_ms", "evaluations", "seconds",
                "cpu_seconds", "window_objective_ms")
        st: dict[str, Any] = {k: np.zeros(n) for k in keys}
        st.update(best_warm=[""] * n, source=[""] * n, base=[""] * n)
        for i in range(n):
            rows = np.nonzero(owner == i)[0]
            j = rows[int(np.argmin(ei[rows]))]
            warm_rows = [r_ for r_ in rows if label[r_] != "cma"]
            w = warm_rows[int(np.argmin(ei[warm_rows]))]
            self.open_loop[:, i] = cols[j]
            st["energy_integral_ms"][i] = ei[j]
            st["best_warm_ms"][i] = ei[w]
            st["improvement_ms"][i] = ei[w] - ei[j]
            st["best_warm"][i] = label[w]
            st["source"][i] = label[j]
            st["base"][i] = searches[i].base
            st["evaluations"][i] = searches[i].evaluations
            st["seconds"][i] = searches[i].seconds
            st["cpu_seconds"][i] = searches[i].cpu_seconds
            st["window_objective_ms"][i] = searches[i].objective
        self.stats = st
        self._k = 0

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """The prepared commands, one step per call (for loops other than ``rollout``)."""
        if self.open_loop is None:
            raise RuntimeError("the oracle is open loop: call prepare(scene, seeds, horizon, warm_starts) "
                               "first (rollout and compare do)")
        if episode_start is not None and np.any(episode_start):
            self._k = 0
        k = min(self._k, self.open_loop.shape[0] - 1)
        self._k += 1
        return self.open_loop[k].reshape(-1, 1).copy(), state  # float64: the commands exactly
