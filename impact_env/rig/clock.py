"""Tick pacing for the target: real time with absolute deadlines, or lock-step on an event.

Real time (``lockstep=False``).  Tick k is due at the absolute deadline
``D_k = t0 + round(k * 1e9 / rate)`` ns of ``time.perf_counter_ns`` (``t0`` set by
:meth:`TickClock.start`), so neither sleep overshoot nor rounding ever accumulates.
:meth:`TickClock.wait` returns when the next tick is due: while more than ``spin_ns`` remain it
sleeps (or hands the time to ``poll(budget_s)``, which must return within about ``budget_s``,
e.g. a socket receive with that timeout), then it spins on the clock up to the deadline, because
an OS sleep wakes up late by tens of microseconds (more on a loaded machine without a real-time
kernel).  ``lateness_ns = start - deadline`` (>= 0) is returned for every tick.

Overruns.  If a tick starts one period or more after its deadline (``lateness >= period``:
the next deadline has passed too), the ticks that cannot be run on time are skipped: the clock
returns the latest due tick, with ``missed`` = the number skipped (its lateness then lies in
``[0, period)``), and counts one overrun.  The target integrates the missed time with the held
command (the virtual rig) and marks the tick (``safety.OVERRUN``): the tick counter stays the
rig's clock, ``t = tick / rate``.

Lock-step (``lockstep=True``).  Time does not pace the ticks: :meth:`TickClock.wait` returns
the next tick as soon as ``ready(k)`` is true (the host's command for it has arrived; or at
once with no ``ready``, as in onboard mode).  ``ready`` is called repeatedly and should block
briefly (a receive with a short timeout).  ``lockstep_timeout_s`` bounds the wait: after it the
tick advances anyway with ``forced = True`` (a dead host cannot freeze the target; the safety
layer's watchdog then counts ticks as usual).  Lateness is 0 in lock-step.

The clock (``now_ns``) and the sleep (``sleep``) are injectable, so the logic is tested with a
fake clock; wall-clock figures belong to ``scripts/bench_rig.py``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from impact_env.config import check_range


@dataclass(frozen=True)
class Tick:
    """One tick to run: its index, its deadline and start (ns of the clock), how late it started,
    how many ticks were skipped before it (an overrun), how long ``wait`` waited (ns), and in
    lock-step whether the timeout rather than the event advanced it."""

    index: int
    deadline_ns: int
    start_ns: int
    lateness_ns: int
    missed: int = 0
    waited_ns: int = 0
    forced: bool = False


class TickClock:
    """Paces ticks at ``rate_hz`` (see the module doc).

    Counters (plain ints): ``ticks`` (returned by ``wait``), ``overruns`` (waits that skipped
    ticks), ``missed`` (ticks skipped in all), ``forced`` (lock-step timeouts), and
    ``max_lateness_ns``.
    """

    def __init__(self, rate_hz: float, lockstep: bool = False, spin_ns: int = 200_000,
                 lockstep_timeout_s: float | None = None, now_ns: Callable[[], int] = time.perf_counter_ns,
                 sleep: Callable[[float], None] = time.sleep):
        check_range("rate_hz", rate_hz, "Hz", 0.0, 1e7, lo_open=True)
        check_range("spin_ns", spin_ns, "ns", 0.0, 1e9)
        if lockstep_timeout_s is not None:
            check_range("lockstep_timeout_s", lockstep_timeout_s, "s", 0.0, None, lo_open=True)
        self.rate_hz = float(rate_hz)
        self.period_ns = 1e9 / self.rate_hz  # float: deadlines are rounded from k * period, never summed
        self.lockstep = bool(lockstep)
        self.spin_ns = int(spin_ns)
        self.lockstep_timeout_ns = None if lockstep_timeout_s is None else int(lockstep_timeout_s * 1e9)
        self.now_ns = now_ns
        self.sleep = sleep
        self.t0_ns: int | None = None
        self.next_index = 0
        self.ticks = self.overruns = self.missed = self.forced = 0
        self.max_lateness_ns = 0

    def deadline(self, index: int) -> int:
        """Absolute deadline of tick ``index``, ns."""
        if self.t0_ns is None:
            raise RuntimeError("TickClock.start() must be called before the first wait()")
        return self.t0_ns + round(index * self.period_ns)

    def start(self, t0_ns: int | None = None, index: int = 0) -> None:
        """Anchor tick ``index`` at ``t0_ns`` (default: now) and reset the counters."""
        self.t0_ns = (self.now_ns() if t0_ns is None else int(t0_ns)) - round(index * self.period_ns)
        self.next_index = int(index)
        self.ticks = self.overruns = self.missed = self.forced = 0
        self.max_lateness_ns = 0

    def wait(self, poll: Callable[[float], object] | None = None,
             ready: Callable[[int], bool] | None = None) -> Tick:
        """Block until the next tick is due (real time) or allowed (lock-step); returns it."""
        if self.t0_ns is None:
            self.start()
        return self._wait_lockstep(ready) if self.lockstep else self._wait_realtime(poll)

    def _wait_realtime(self, poll) -> Tick:
        k = self.next_index
        deadline = self.deadline(k)
        t_in = now = self.now_ns()
        while (remaining := deadline - now) > 0:
            if remaining > self.spin_ns:
                budget_s = (remaining - self.spin_ns) * 1e-9
                if poll is not None:
                    poll(budget_s)
                else:
                    self.sleep(budget_s)
            now = self.now_ns()
        late = now - deadline
        missed = 0
        if late >= self.period_ns:
            missed = int(late // self.period_ns)
            k += missed
            deadline = self.deadline(k)
            if deadline > now:  # float rounding at the boundary: stay on the tick that is due
                missed -= 1
                k -= 1
                deadline = self.deadline(k)
            late = now - deadline
            if missed > 0:
                self.overruns += 1
                self.missed += missed
        self.next_index = k + 1
        self.ticks += 1
        self.max_lateness_ns = max(self.max_lateness_ns, late)
        return Tick(k, deadline, now, late, missed, now - t_in)

    def _wait_lockstep(self, ready) -> Tick:
        k = self.next_index
        t_in = now = self.now_ns()
        forced = False
        if ready is not None:
            while not ready(k):
                now = self.now_ns()
                if self.lockstep_timeout_ns is not None and now - t_in >= self.lockstep_timeout_ns:
                    forced = True
                    break
            now = self.now_ns()
        self.forced += forced
        self.next_index = k + 1
        self.ticks += 1
        return Tick(k, now, now, 0, 0, now - t_in, forced)

    def counters(self) -> dict[str, int]:
        return {"ticks": self.ticks, "overruns": self.overruns, "missed_ticks": self.missed,
                "lockstep_timeouts": self.forced, "max_lateness_ns": int(self.max_lateness_ns)}


def lateness_summary(lateness_ns, ticks: int | None = None, overruns: int = 0) -> dict[str, float]:
    """Percentiles of tick lateness (p50, p99, p99.9, max; in us) and overruns per 1e5 ticks."""
    x = np.asarray(lateness_ns, dtype=np.float64)
    if x.size == 0:
        raise ValueError("no lateness samples")
    n = x.size if ticks is None else int(ticks)
    p50, p99, p999 = np.percentile(x, [50.0, 99.0, 99.9]) / 1e3
    return {"p50_us": float(p50), "p99_us": float(p99), "p999_us": float(p999),
            "max_us": float(x.max() / 1e3), "overruns_per_1e5": 1e5 * overruns / n if n else math.nan,
            "ticks": n}
