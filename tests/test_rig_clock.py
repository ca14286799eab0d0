"""Tick pacing (impact_env.rig.clock), with an injected fake clock: deterministic, no wall time."""

from __future__ import annotations

import numpy as np
import pytest

from impact_env.config import ConfigError
from impact_env.rig.clock import TickClock, lateness_summary

PERIOD = 100_000  # ns at 10 kHz


class FakeTime:
    """A clock that advances by ``read_ns`` per reading (the cost of reading it while spinning)
    and by the requested time plus an oversleep from ``oversleep`` per sleep."""

    def __init__(self, t0=5_000_000_000, read_ns=50, oversleep=lambda: 0):
        self.t = t0
        self.read_ns = read_ns
        self.oversleep = oversleep
        self.sleeps: list[float] = []
        self.reads = 0

    def now_ns(self):
        self.t += self.read_ns
        self.reads += 1
        return self.t

    def sleep(self, s):
        self.sleeps.append(s)
        self.t += int(s * 1e9) + self.oversleep()

    def work(self, ns):  # the tick's computation
        self.t += ns


def make(ft, **kw):
    return TickClock(1.0e4, now_ns=ft.now_ns, sleep=ft.sleep, **kw)


def test_deadlines_are_absolute_and_oversleep_does_not_accumulate():
    rng = np.random.default_rng(2)
    ft = FakeTime(read_ns=1_000, oversleep=lambda: int(rng.integers(0, 150_000)))  # wake up <= 150 us late
    clk = make(ft, spin_ns=200_000)
    clk.start()
    t0 = clk.t0_ns
    ticks = []
    for _ in range(2000):
        tick = clk.wait()
        ticks.append(tick)
        ft.work(20_000)
    idx = np.array([t.index for t in ticks])
    dl = np.array([t.deadline_ns for t in ticks])
    np.testing.assert_array_equal(dl, t0 + idx * PERIOD)  # every deadline on the absolute grid
    late = np.array([t.lateness_ns for t in ticks])
    assert late.min() >= 0 and late.max() < PERIOD
    # the sleep stops spin_ns before the deadline, so an oversleep below spin_ns never makes a tick
    # late by more than one clock reading; longer ones (150 us > 200 us - 100 us work) are absorbed
    assert np.all(idx == np.arange(2000)) and clk.overruns == 0
    assert late.max() <= 150_000 and np.median(late) < 1_000


def test_sleep_then_spin():
    ft = FakeTime(read_ns=1_000)
    clk = make(ft, spin_ns=30_000)
    clk.start()
    clk.wait()  # tick 0 is due at once
    ft.sleeps.clear()
    ft.reads = 0
    tick = clk.wait()
    assert tick.index == 1
    assert len(ft.sleeps) == 1 and ft.sleeps[0] == pytest.approx((PERIOD - 30_000 - 2_000) * 1e-9, abs=2e-9)
    assert ft.reads > 20  # the last 30 us were spun, reading the clock every 1 us
    assert 0 <= tick.lateness_ns < 1_000


def test_poll_gets_the_idle_time_instead_of_sleep():
    ft = FakeTime()
    budgets = []

    def poll(budget_s):
        budgets.append(budget_s)
        ft.work(int(budget_s * 1e9))

    clk = make(ft, spin_ns=20_000)
    clk.start()
    clk.wait(poll=poll)
    clk.wait(poll=poll)
    assert ft.sleeps == [] and len(budgets) == 1 and budgets[0] == pytest.approx(79.9e-6, abs=1e-7)


@pytest.mark.parametrize("work_periods,missed",
                         [(0.5, 0), (0.99, 0), (1.0, 1), (1.2, 1), (3.5, 3), (10.0, 10)])
def test_overrun_skips_the_ticks_that_cannot_run_on_time(work_periods, missed):
    ft = FakeTime(read_ns=1)
    clk = make(ft)
    clk.start()
    assert clk.wait().index == 0  # returns at t0 + 1 ns (one clock reading)
    ft.work(int((1 + work_periods) * PERIOD))  # tick 0 computes for too long
    tick = clk.wait()
    assert tick.missed == missed and tick.index == 1 + missed
    assert 0 <= tick.lateness_ns < PERIOD
    expected = 1 + int((1 + work_periods) * PERIOD) + 1 - (1 + missed) * PERIOD
    assert tick.lateness_ns == expected or (expected <= 0 and tick.lateness_ns < 10)
    assert clk.overruns == (missed > 0) and clk.missed == missed
    assert clk.wait().index == 2 + missed  # then back on the grid
    assert clk.counters()["missed_ticks"] == missed


def test_start_anchors_a_tick_index():
    ft = FakeTime(read_ns=1)
    clk = make(ft)
    clk.start(t0_ns=1_000_000_000, index=50)
    assert clk.deadline(50) == 1_000_000_000 and clk.deadline(51) == 1_000_100_000
    ft.t = 1_000_000_000 - 10
    assert clk.wait().index == 50


def test_non_integer_periods_round_each_deadline_from_the_start():
    ft = FakeTime(read_ns=0)
    clk = TickClock(3000.0, now_ns=ft.now_ns, sleep=ft.sleep)  # 333333.33 ns
    clk.start(t0_ns=0)
    assert [clk.deadline(k) for k in (1, 2, 3, 3000)] == [333333, 666667, 1000000, 1_000_000_000]


def test_lockstep_advances_on_the_event_and_times_out():
    ft = FakeTime(read_ns=1_000)
    calls = []

    def ready(k):
        calls.append(k)
        return len(calls) % 3 == 0  # the command arrives on the third look

    clk = make(ft, lockstep=True, lockstep_timeout_s=1e-3)
    clk.start()
    ticks = [clk.wait(ready=ready) for _ in range(4)]
    assert [t.index for t in ticks] == [0, 1, 2, 3] and not any(t.forced for t in ticks)
    assert calls == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3] and ft.sleeps == []
    assert all(t.lateness_ns == 0 and t.waited_ns > 0 for t in ticks)
    never = clk.wait(ready=lambda k: False)  # a dead host: the timeout advances the tick
    assert never.forced and never.index == 4 and never.waited_ns >= 1_000_000
    assert clk.wait().index == 5  # onboard: no event to wait for
    assert clk.counters()["lockstep_timeouts"] == 1 and clk.counters()["ticks"] == 6


@pytest.mark.parametrize("kw,match", [
    ({"rate_hz": 0.0}, "rate_hz = 0.0 Hz"), ({"rate_hz": 1e4, "spin_ns": -1}, "spin_ns"),
    ({"rate_hz": 1e4, "lockstep_timeout_s": 0.0}, "lockstep_timeout_s")])
def test_argument_errors(kw, match):
    with pytest.raises(ConfigError, match=match):
        TickClock(**kw)


def test_deadline_before_start_is_an_error():
    with pytest.raises(RuntimeError, match="start"):
        TickClock(1e4).deadline(0)


def test_lateness_summary():
    s = lateness_summary(np.arange(1000) * 1000, overruns=2)
    assert s["p50_us"] == pytest.approx(499.5) and s["max_us"] == 999.0
    assert s["overruns_per_1e5"] == 200.0 and s["ticks"] == 1000
    with pytest.raises(ValueError):
        lateness_summary([])
