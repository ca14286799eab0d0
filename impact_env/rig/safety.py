"""The target's safety layer: what may reach the shaker, tick by tick (a numba kernel).

Every tick the target passes the demanded command through :func:`safety_step`, which returns the
force to apply (N, up positive, the thesis's f2) and status bits.  Its inputs:

* ``demand``: the command, dimensionless (1.0 = the scene's ``effects.command_scale`` newtons):
  the host's latest COMMAND in host mode, the onboard policy's output in onboard mode.
* ``age_ticks``: ticks since the first tick of the policy step the command in use is for (the
  controller passes ``m - step H``: a command that arrived late in its step gets no extra
  time; < 0: no command yet this episode).  Host mode only; onboard mode passes 0.
* ``ticks_armed``: ticks since the episode was armed.
* ``x2_m``: the potentiometer's reading of body 2's travel (m, down positive, 0 at rest), as the
  plausibility check passed it (:mod:`impact_env.control.plausibility`: the last plausible one
  when this tick's was not).
* ``sensor_bits``: the plausibility check's status bits for this tick (0: every reading plausible).

Rules, in the order applied (host mode = ``mode="host"``; H = hold_ticks):

1. **Watchdog** (host mode).  A command acts in its own step (``age < H``) and is repeated
   through the next (``H <= age < 2H``: ``REPEATED``); from ``age = 2H`` on the force is 0
   (``WATCHDOG``) until a new command arrives.  So the demanded force is 0 within 2 policy
   periods of the last command's step (the shaker's own response then decays it).
   Each start of a watchdog stretch counts one trip.
2. **First command.**  Before the first command the force is 0 (``NO_COMMAND``); once
   ``ticks_armed`` reaches ``first_command_timeout_s`` (in ticks, rounded up) with none,
   ``FIRST_COMMAND_TIMEOUT`` is set: the target disarms, unless a COMMAND of the episode came
   after its step was over (the real-time loop clears the bit then, :mod:`impact_env.rig.rtloop`:
   the host answers, late, and its ticks stay at 0 N until one of its commands acts).
3. **Non-finite** demand (NaN, inf, or a product with the command scale that overflows):
   0 N for this tick, ``NONFINITE``.
4. **Implausible readings** (:mod:`impact_env.control.plausibility`): any ``sensor_bits``
   (``SENSOR_FAULT`` and the channel's bit; ``SENSOR_TIMEOUT`` once the fault outlasted
   ``effects.sensors.fault_limit_s``, latched by the check): 0 N for this tick, never a force
   from a bad sample.  A non-finite ``x2_m`` (a caller without the check) is a potentiometer
   fault the same way.
5. **Travel limit** (latched).  ``|x2| > travel_limit_m`` sets ``TRAVEL``: the force stays 0 for
   the rest of the episode (the suspension brings body 2 back; a policy that drove the armature
   out of its stroke is not trusted to bring it back), and the bit is reported on every later
   tick.
6. **Peak clamp**: ``|f| <= peak_n`` (``CLAMP_PEAK``).
7. **Continuous (RMS) clamp**: the RMS of the applied force over any window of
   ``rms_window_s`` (n = rate * window ticks, this one included) stays at or below
   ``continuous_n / sqrt(2)`` (the RMS of a sine of peak ``continuous_n``): the allowed
   ``f^2`` is ``n R^2`` minus the sum of the other n-1 squares in the window (``CLAMP_RMS``).
   The window keeps running between episodes (the coil's heat does not reset with an episode):
   call :func:`drain_window` for idle ticks.  Squares are stored as whole multiples of a quantum
   (1e-6 N^2, or coarser so that n peak^2 stays below 2^50 quanta), so the running sum is exact.

Ratings and limits (:class:`SafetyConfig`, SI units):

* ``peak_n`` = 200 N: the LDS V406 / PA 100E gave "approximately 200 N" for short pulses
  (thesis sec 4.3).
* ``continuous_n`` = 98 N: its sine peak rating (thesis sec 4.1), i.e. 69.3 N RMS.
* ``rms_window_s`` = 1 s: **ASSUMED** (the thesis gives no thermal time constant).  With it a
  200 N command may last 0.12 s in any second (n R^2 / (200 N)^2), far longer than a contact
  (about 4 ms), so a catch is never clamped, while a stuck full-scale command is.
* ``travel_limit_m`` = 7 mm: **ASSUMED**, 80 % of the V406's +-8.8 mm half stroke (17.6 mm
  peak to peak in LDS's data sheet, not in the thesis; check the rig's own exciter).  It lies
  inside the simulated potentiometer's +-10 mm range (``effects.sensors.potentiometer``).
* ``first_command_timeout_s`` = 0.1 s: **ASSUMED**, a thousand ticks at 10 kHz, far above a
  loopback round trip (about 0.1 ms) and a Python host's first step (about 1 ms).

Status bits (u32; bits 0-15 this layer, 16-31 the target loop):

====  =========================  ==============================================================
bit   name                       meaning
====  =========================  ==============================================================
0     ``NO_COMMAND``             host mode, no command yet this episode: 0 N
1     ``REPEATED``               the command is in its repeat period (age in [H, 2H))
2     ``WATCHDOG``               the command is older than 2 periods: 0 N
3     ``FIRST_COMMAND_TIMEOUT``  no command (on time or late) within the timeout: disarm
4     ``NONFINITE``              the demand was NaN or infinite: 0 N
5     ``CLAMP_PEAK``             the peak clamp cut the force
6     ``CLAMP_RMS``              the continuous (RMS) clamp cut the force
7     ``TRAVEL``                 (latched) body 2 beyond its travel limit: 0 N
8     ``SENSOR_FAULT``           a reading of this tick was implausible (out of the converter's
                                 range, NaN/inf, or a jump no physics gives): 0 N, held readings
9-12  ``SENSOR_ACCELEROMETER``,  which channel(s) (accelerometer, force transducer, potentiometer,
      ``_FORCE``,                body-1 sensor)
      ``_POTENTIOMETER``,
      ``_BODY1``
13    ``SENSOR_TIMEOUT``         (latched) implausible readings outlasted fault_limit_s: 0 N; the
                                 target ends the episode SENSOR_FAULT
16    ``OVERRUN``                (target loop) the tick started a period or more late, or ticks
                                 were skipped just before it (the log's ``skipped_ticks``)
====  =========================  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.config import ConfigError, check_hold_ticks, check_range, doc_field
from impact_env.control import plausibility

NO_COMMAND = 1 << 0
REPEATED = 1 << 1
WATCHDOG = 1 << 2
FIRST_COMMAND_TIMEOUT = 1 << 3
NONFINITE = 1 << 4
CLAMP_PEAK = 1 << 5
CLAMP_RMS = 1 << 6
TRAVEL = 1 << 7
# the plausibility check's bits (impact_env.control.plausibility: it runs below this layer)
SENSOR_FAULT = plausibility.SENSOR_FAULT
SENSOR_ACCELEROMETER = plausibility.SENSOR_ACCELEROMETER
SENSOR_FORCE = plausibility.SENSOR_FORCE
SENSOR_POTENTIOMETER = plausibility.SENSOR_POTENTIOMETER
SENSOR_BODY1 = plausibility.SENSOR_BODY1
SENSOR_TIMEOUT = plausibility.SENSOR_TIMEOUT
SENSOR_BITS = plausibility.SENSOR_BITS
OVERRUN = 1 << 16
LATCHING = TRAVEL
FORCE_ZEROED = NO_COMMAND | WATCHDOG | NONFINITE | TRAVEL | SENSOR_FAULT | SENSOR_TIMEOUT

STATUS_BITS = {"NO_COMMAND": NO_COMMAND, "REPEATED": REPEATED, "WATCHDOG": WATCHDOG,
               "FIRST_COMMAND_TIMEOUT": FIRST_COMMAND_TIMEOUT, "NONFINITE": NONFINITE,
               "CLAMP_PEAK": CLAMP_PEAK, "CLAMP_RMS": CLAMP_RMS, "TRAVEL": TRAVEL,
               "SENSOR_FAULT": SENSOR_FAULT, "SENSOR_ACCELEROMETER": SENSOR_ACCELEROMETER,
               "SENSOR_FORCE": SENSOR_FORCE, "SENSOR_POTENTIOMETER": SENSOR_POTENTIOMETER,
               "SENSOR_BODY1": SENSOR_BODY1, "SENSOR_TIMEOUT": SENSOR_TIMEOUT, "OVERRUN": OVERRUN}

class SafetyParams(NamedTuple):
    """The safety layer's parameters (float64[N_PARAMS]), read by name: ``p[PARAM.peak]``."""

    scale: int  # N per unit command
    peak: int  # N, the peak clamp
    budget: int  # quanta of f^2 the RMS window may hold (-1: no RMS clamp)
    quantum: int  # N^2 per quantum
    window: int  # ticks of the RMS window
    travel: int  # m, the travel limit
    first: int  # ticks: host mode's allowance for the first command
    hold: int  # ticks per policy step
    host: int  # 1.0: host mode (the watchdog on), 0.0: onboard


class SafetyState(NamedTuple):
    """The safety layer's fixed state (float64[N_STATE_FIXED + window]: then the ring of the
    window's squares, in quanta), read by name: ``s[STATE.latch]``."""

    latch: int  # latched status bits
    sum: int  # the window's running sum of squares (quanta)
    head: int  # the ring's head
    prev_watchdog: int  # 1.0: the last tick was WATCHDOG (a trip counts once)
    watchdog_trips: int
    nonfinite_ticks: int
    clamp_peak_ticks: int
    clamp_rms_ticks: int
    travel_trips: int
    sensor_fault_ticks: int


PARAM = positions(SafetyParams)
N_PARAMS = len(PARAM)
STATE = positions(SafetyState)
N_STATE_FIXED = len(STATE)
# the per-episode counters (state entries named as the log's counters)
COUNTERS = {name: getattr(STATE, name) for name in ("watchdog_trips", "nonfinite_ticks", "clamp_peak_ticks",
                                                     "clamp_rms_ticks", "travel_trips", "sensor_fault_ticks")}
# plain-int aliases for the C export (impact_env.deploy.c_export), which still reads them
P_SCALE, P_PEAK, P_BUDGET, P_QUANTUM, P_WINDOW, P_TRAVEL, P_FIRST = PARAM[:7]
MAX_WINDOW = 10_000_000  # ticks (80 MB of state): a guard against a mistyped window or rate

_f = doc_field


@dataclass(frozen=True)
class SafetyConfig:
    """Limits the target enforces on the force it sends to the shaker (see the module doc)."""

    peak_n: float = _f(200.0, "N", "peak clamp |f| (thesis sec 4.3: about 200 N for short pulses)")
    continuous_n: float = _f(98.0, "N", "continuous rating as a sine peak (thesis sec 4.1: 98 N); the RMS "
                             "over rms_window_s may not exceed continuous_n/sqrt(2); 0 = no RMS clamp")
    rms_window_s: float = _f(1.0, "s", "window of the RMS clamp (ASSUMED: no thermal data in the thesis)")
    travel_limit_m: float = _f(7.0e-3, "m", "|x2| beyond which the force is cut and latched off (ASSUMED: "
                               "80 % of the V406's 8.8 mm half stroke)")
    first_command_timeout_s: float = _f(0.1, "s", "host mode: disarm if no first command within it (ASSUMED)")

    def __post_init__(self):
        check_range("safety.peak_n", self.peak_n, "N", 0.0, None, lo_open=True)
        check_range("safety.continuous_n", self.continuous_n, "N", 0.0, self.peak_n)
        check_range("safety.rms_window_s", self.rms_window_s, "s", 0.0, 600.0, lo_open=True)
        check_range("safety.travel_limit_m", self.travel_limit_m, "m", 0.0, 1.0, lo_open=True)
        check_range("safety.first_command_timeout_s", self.first_command_timeout_s, "s", 0.0, 3600.0,
                    lo_open=True)

    @property
    def rms_limit_n(self) -> float:
        """The RMS force allowed over the window, N."""
        return self.continuous_n / math.sqrt(2.0)


def safety_params(cfg: SafetyConfig, command_scale: float, rate: float, hold_ticks: int,
                  mode: str = "host") -> np.ndarray:
    """float64[N_PARAMS] for :func:`safety_step`: the config at the control ``rate`` (Hz), for
    ``command_scale`` N per unit demand, ``hold_ticks`` ticks per policy step, ``mode``
    "host" (watchdog on) or "onboard"."""
    check_range("effects.command_scale", command_scale, "N", 0.0, None, lo_open=True)
    check_range("control.rate", rate, "Hz", 0.0, 1e8, lo_open=True)
    check_hold_ticks(hold_ticks)
    if mode not in ("host", "onboard"):
        raise ConfigError(f"mode = {mode!r} must be 'host' or 'onboard'")
    n = max(1, int(round(cfg.rms_window_s * rate)))
    if n > MAX_WINDOW:
        raise ConfigError(f"safety.rms_window_s = {cfg.rms_window_s:g} s at {rate:g} Hz is {n} ticks; "
                          f"at most {MAX_WINDOW} (shorten the window)")
    quantum = max(1e-6, cfg.peak_n**2 * n / 2.0**50)
    p = np.empty(N_PARAMS)
    p[PARAM.scale] = command_scale
    p[PARAM.peak] = cfg.peak_n
    p[PARAM.budget] = math.floor(n * cfg.rms_limit_n**2 / quantum) if cfg.continuous_n > 0 else -1.0
    p[PARAM.quantum] = quantum
    p[PARAM.window] = n
    p[PARAM.travel] = cfg.travel_limit_m
    p[PARAM.first] = math.ceil(cfg.first_command_timeout_s * rate - 1e-9)
    p[PARAM.hold] = hold_ticks
    p[PARAM.host] = 1.0 if mode == "host" else 0.0
    return p


def make_safety_state(params: np.ndarray) -> np.ndarray:
    """Zeroed state for ``params``: no latches, an empty (cool) RMS window."""
    return np.zeros(N_STATE_FIXED + int(params[PARAM.window]))


def new_episode(state: np.ndarray) -> np.ndarray:
    """Clear the latches and counters for a new episode; the RMS window (heat) is kept."""
    state[STATE.latch] = 0.0
    state[STATE.prev_watchdog] = 0.0
    for i in COUNTERS.values():
        state[i] = 0.0
    return state


@jit
def drain_window(state, params, n_ticks):
    """Push ``n_ticks`` idle (0 N) ticks into the RMS window (time spent disarmed)."""
    n = int(params[PARAM.window])
    head = int(state[STATE.head])
    for _ in range(min(n_ticks, n)):
        state[STATE.sum] -= state[N_STATE_FIXED + head]
        state[N_STATE_FIXED + head] = 0.0
        head = (head + 1) % n
    state[STATE.head] = head


@jit
def safety_step(demand, age_ticks, ticks_armed, x2_m, sensor_bits, params, state):
    """One tick of the safety layer (module doc): returns ``(force_N, status)``, the force to
    apply (N, up positive) and the status bits (int64); updates ``state``."""
    status = 0
    use = True
    hold = params[PARAM.hold]
    if params[PARAM.host] != 0.0:
        if age_ticks < 0:
            status |= NO_COMMAND
            use = False
            if ticks_armed >= params[PARAM.first]:
                status |= FIRST_COMMAND_TIMEOUT
        elif age_ticks >= 2.0 * hold:
            status |= WATCHDOG
            use = False
        elif age_ticks >= hold:
            status |= REPEATED
    if status & WATCHDOG:
        if state[STATE.prev_watchdog] == 0.0:
            state[STATE.watchdog_trips] += 1.0
        state[STATE.prev_watchdog] = 1.0
    else:
        state[STATE.prev_watchdog] = 0.0
    f = 0.0
    if use:
        f = demand * params[PARAM.scale]
        if not np.isfinite(f):
            status |= NONFINITE
            state[STATE.nonfinite_ticks] += 1.0
            f = 0.0
    if not np.isfinite(x2_m):
        sensor_bits |= SENSOR_FAULT | SENSOR_POTENTIOMETER
    if sensor_bits != 0:
        status |= sensor_bits
        state[STATE.sensor_fault_ticks] += 1.0
        f = 0.0
    latch = int(state[STATE.latch])
    if np.isfinite(x2_m) and abs(x2_m) > params[PARAM.travel]:
        if (latch & TRAVEL) == 0:
            state[STATE.travel_trips] += 1.0
        latch |= TRAVEL
    state[STATE.latch] = latch
    if latch != 0:
        status |= latch
        f = 0.0
    peak = params[PARAM.peak]
    if f > peak:
        f = peak
        status |= CLAMP_PEAK
    elif f < -peak:
        f = -peak
        status |= CLAMP_PEAK
    if status & CLAMP_PEAK:
        state[STATE.clamp_peak_ticks] += 1.0
    # RMS window: the oldest square leaves, this tick's enters
    n = int(params[PARAM.window])
    head = int(state[STATE.head])
    slot = N_STATE_FIXED + head
    others = state[STATE.sum] - state[slot]
    q_unit = params[PARAM.quantum]
    sq = np.floor(f * f / q_unit + 0.5)
    budget = params[PARAM.budget]
    if budget >= 0.0 and others + sq > budget:
        room = budget - others
        if room < 0.0:
            room = 0.0
        mag = np.sqrt(room * q_unit)
        f = mag if f > 0.0 else -mag
        sq = np.floor(f * f / q_unit + 0.5)
        if sq > room:
            sq = room
        status |= CLAMP_RMS
        state[STATE.clamp_rms_ticks] += 1.0
    state[slot] = sq
    state[STATE.sum] = others + sq
    state[STATE.head] = (head + 1) % n
    return f, status


def describe_status(bits: int) -> list[str]:
    """Names of the bits set in ``bits``, in bit order (unknown bits as ``bitN``)."""
    bits = int(bits)
    known = {v: k for k, v in STATUS_BITS.items()}
    return [known.get(1 << i, f"bit{i}") for i in range(32) if bits >> i & 1]


class SafetyLayer:
    """The safety layer of one rig: the config turned into ``params`` and ``state``.

    The target's controller (:class:`impact_env.rig.controller.Controller`) holds one; its
    compiled tick calls :func:`safety_step` with ``layer.params`` and ``layer.state`` directly;
    :meth:`step` does the same from Python.
    """

    def __init__(self, cfg: SafetyConfig | None = None, command_scale: float = 200.0, rate: float = 1.0e4,
                 hold_ticks: int = 1, mode: str = "host"):
        self.cfg = cfg or SafetyConfig()
        self.params = safety_params(self.cfg, command_scale, rate, hold_ticks, mode)
        self.state = make_safety_state(self.params)

    def step(self, demand: float, age_ticks: int, ticks_armed: int, x2_m: float,
             sensor_bits: int = 0) -> tuple[float, int]:
        f, status = safety_step(float(demand), int(age_ticks), int(ticks_armed), float(x2_m),
                                int(sensor_bits), self.params, self.state)
        return float(f), int(status)

    def new_episode(self) -> None:
        new_episode(self.state)

    def drain(self, n_ticks: int) -> None:
        drain_window(self.state, self.params, int(n_ticks))

    @property
    def window_rms_n(self) -> float:
        """RMS of the applied force over the current window, N."""
        return math.sqrt(self.state[STATE.sum] * self.params[PARAM.quantum] / self.params[PARAM.window])

    @property
    def latched(self) -> int:
        return int(self.state[STATE.latch])

    def counters(self) -> dict[str, int]:
        """Per-episode counts (plain ints): watchdog trips, non-finite ticks, clamped ticks, travel trips,
        ticks with implausible readings."""
        return {name: int(self.state[i]) for name, i in COUNTERS.items()}
