"""Sensor faults injected into closed-loop drops: the rig target's compiled tick (the
controller, onboard, :mod:`impact_env.rig.controller`) on the virtual rig's hardware stage, one
drop per call, every tick in compiled code, and a fault of one kind on one channel added to the
readings the controller is given (the plant does not see it: a sensor's fault is not the
plant's).  What the plausibility check (:mod:`impact_env.control.plausibility`) makes of them
is measured by ``scripts/fault_detection.py`` and tested by ``tests/test_sensor_faults.py``;
docs/rig/faults.md has the kinds and what the check derives for them.

Kinds (``Fault.kind``), from tick ``tick`` on, on channel ``channel`` (0 accelerometer, 1 force
transducer, 2 potentiometer):

* ``spike``: one reading off by ``size`` (the channel's unit);
* ``step``: every reading from ``tick`` on off by ``size`` (an offset appearing);
* ``stuck``: every reading from ``tick`` on equal to the one before ``tick`` (``size`` unused);
* ``stuck_at``: every reading from ``tick`` on equal to ``size`` (e.g. -0.0: a dead converter);
* ``dropout``: ``length`` readings of 0.0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from gymnasium.utils import seeding

from impact_env._jit import jit
from impact_env._packed import positions
from impact_env.control.observation import make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.effects.sensors import N_CHANNELS
from impact_env.hardware.batch import Hardware
from impact_env.hardware.stage import state_ok, tick
from impact_env.rig.controller import Controller, HostCommand, act_tick, observe_tick

KINDS = ("spike", "step", "stuck", "stuck_at", "dropout")
NO_FAULT = -1
NAN4 = np.full(4, np.nan)


class FaultSlots(NamedTuple):
    """The entries of a fault's float64 vector (:meth:`Fault.array`), as the compiled tick reads them."""

    channel: float  # 0 accelerometer, 1 force transducer, 2 potentiometer
    kind: float  # index in KINDS, or NO_FAULT
    first_tick: float  # the first tick it acts on
    size: float  # the channel's unit
    end_tick: float  # the last tick it acts on + 1


FAULT = positions(FaultSlots)


@dataclass(frozen=True)
class Fault:
    """One injected fault (module doc)."""

    channel: int
    kind: str
    tick: int
    size: float = 0.0
    length: int = 1

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"fault kind {self.kind!r}: one of {', '.join(KINDS)}")
        if not 0 <= self.channel < N_CHANNELS:
            raise ValueError(f"fault channel {self.channel}: 0 to {N_CHANNELS - 1}")
        if self.tick < 1:
            raise ValueError(f"fault tick {self.tick}: from 1 (tick 0's readings start the front end)")

    def array(self) -> np.ndarray:
        """float64[len(FAULT)]: its entries by name (:class:`FaultSlots`)."""
        length = 1 if self.kind == "spike" else (self.length if self.kind == "dropout" else 1 << 40)
        return np.array(FaultSlots(channel=self.channel, kind=KINDS.index(self.kind), first_tick=self.tick,
                                   size=self.size, end_tick=self.tick + length), dtype=np.float64)


NONE = np.array(FaultSlots(channel=0.0, kind=NO_FAULT, first_tick=0.0, size=0.0, end_tick=0.0),
                dtype=np.float64)


@jit(inline="always")
def _inject(m, reading, fault, before):
    """The controller's reading of tick m with the fault applied (``reading``: float64[4], in
    place); ``before``: the channel's reading just before the fault (stuck)."""
    c = int(fault[FAULT.channel])
    kind = int(fault[FAULT.kind])
    if kind == NO_FAULT or m < fault[FAULT.first_tick] or m >= fault[FAULT.end_tick]:
        return
    if kind == 0 or kind == 1:  # spike, step
        reading[c] += fault[FAULT.size]
    elif kind == 2:  # stuck
        reading[c] = before[0]
    elif kind == 3:  # stuck at a value
        reading[c] = fault[FAULT.size]
    else:  # dropout
        reading[c] = 0.0


@jit
def run_ticks(m0, m1, p, s, hw_p, hw_s, fault, before, readings, force, status):
    """Ticks m0 .. m1 - 1 of a drop whose tick 0 :meth:`Controller.start` and :func:`act_tick`
    ran (the hardware's noise topped up for them); fills the readings the controller was given,
    the force it demanded (N) and its status.  Returns the next tick (m1, or the tick after
    the one whose simulation failed)."""
    truth = np.full(4, np.nan)
    c = int(fault[FAULT.channel])
    for m in range(m0, m1):
        r = readings[m]
        raw = hw_s.out.raw[0]
        for j in range(r.shape[0]):
            r[j] = raw[j]
        if m == fault[FAULT.first_tick]:
            before[0] = readings[m - 1, c]
        _inject(m, r, fault, before)
        observe_tick(m, r, truth, p, s)
        out, f, st, _row = act_tick(m, m, HostCommand(0.0, -1, -1), p, s, r)
        force[m] = f
        status[m] = st
        tick(0, out, hw_p, hw_s)
        if not state_ok(0, hw_s):
            return m + 1
    return m1


@dataclass
class Drop:
    """One drop's record: the readings the controller was given (float64[n, 4]), its force
    demand after safety (N) and status word per tick, the fault (None: clean)."""

    readings: np.ndarray
    force: np.ndarray
    status: np.ndarray
    fault: Fault | None


class DropRunner:
    """The controller for ``policy`` (onboard) on ``scene``'s virtual rig hardware, ``ticks`` per
    drop.  :meth:`run` runs drop ``seed`` (the drop and noise ``ImpactCatch-v0`` meets for that
    reset seed, as :class:`impact_env.rig.driver.VirtualRig`) with an optional fault."""

    def __init__(self, policy: CompiledPolicy, scene, ticks: int):
        self.scene, self.ticks = scene, int(ticks)
        layout = make_layout(scene, policy.observation, policy.history)
        self.ctl = Controller(scene, layout, policy.hold_ticks, self.ticks, "onboard", policy,
                              policy.residual_policy())
        self.hw = Hardware(scene, 1)

    def run(self, seed: int, fault: Fault | None = None) -> Drop:
        n = self.ticks
        hw = self.hw
        hw.reset([seeding.np_random(int(seed))[0]])
        hw.refill_noise(1)
        readings = np.zeros((n, N_CHANNELS))
        force = np.zeros(n)
        status = np.zeros(n, dtype=np.int64)
        readings[0] = hw.raw[0]
        ctl = self.ctl
        ctl.start(readings[0].copy(), None)
        _cmd, f, st, _row = ctl.act(0, 0.0, -1, -1, 0, readings[0])
        tick(0, _cmd, hw.params, hw.state)
        force[0], status[0] = f, st
        fa = NONE if fault is None else fault.array()
        before = np.zeros(1)
        m = 1
        while m < n:  # in blocks of the hardware's noise block
            m1 = min(n, m + hw.noise_block)
            hw.refill_noise(m1 - m)
            m_next = run_ticks(m, m1, ctl.params, ctl.state, hw.params, hw.state, fa, before, readings, force,
                               status)
            if m_next < m1:
                return Drop(readings[:m_next], force[:m_next], status[:m_next], fault)
            m = m1
        return Drop(readings, force, status, fault)


def first_flag(status: np.ndarray, bits: int, start: int = 0) -> int:
    """The first tick at or after ``start`` whose status has any of ``bits`` (-1: none)."""
    hit = np.flatnonzero(np.asarray(status[start:], dtype=np.int64) & int(bits))
    return int(hit[0]) + start if hit.size else -1
