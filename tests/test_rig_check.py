"""``impact-env rig check`` (impact_env.rig.check) and what ``rig serve`` applies of its placement
(impact_env.rig.placement).  The verdict is a function of lateness samples: the tests give it
samples (a stall of a known length, a tail of known size), never this machine's own latency; the
kernel's facts are read from a fake /proc and /sys."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from impact_env.rig import check as rig_check
from impact_env.rig import placement


def _measurement(late_ns, longest_gap_ns=0.0, rate_hz=10_000.0, cpu=1, policy="SCHED_FIFO 50"):
    late = np.asarray(late_ns, dtype=float)
    return rig_check.Measurement(
        np.zeros(10, np.int64),
        late,
        np.zeros(late.size, np.int64),
        float(longest_gap_ns),
        rate_hz,
        1_000_000,
        cpu,
        policy,
        0.0,
    )


def _facts(**kw):
    base = dict(release="6.1.0", version="#1 SMP PREEMPT_DYNAMIC", preempt_model="dynamic",
                rt_runtime_us=950000, rt_period_us=1000000, autogroup=True, cpus=[0, 1], may_fifo=True,
                fifo_max=99, may_mlock=True,
                clocksource="tsc", clocksources=["tsc", "hpet"])
    base.update(kw)
    return rig_check.KernelFacts(**base)


def test_a_quiet_loop_sustains_every_rate_and_hold_one_at_ten_khz():
    """Lateness of 1-5 us on every tick, no stretch without a tick: 10 kHz onboard, host mode from
    hold 1 for a host 50 us away (50 + 5 us < 0.8 periods of 100 us)."""
    rng = np.random.default_rng(0)
    m = _measurement(rng.uniform(1e3, 5e3, 20_000), longest_gap_ns=105e3)
    v = rig_check.verdict(m, _facts(), max_gap_s=1e-3, host_round_trip_us=50.0)
    r10 = next(r for r in v.rates if r.rate_hz == 10_000.0)
    assert r10.sustained and r10.overrun_share == 0.0 and r10.min_hold == 1 and r10.holds[1] == 1.0
    assert v.max_rate_hz == max(rig_check.RATES_HZ)


def test_a_stall_longer_than_the_gap_limit_sustains_no_rate():
    """One stretch of 2.5 ms without a tick (the fault, shown in the samples): the target's 1 ms
    limit would end the episode OVERRUN at any rate, and the verdict says so by name."""
    late = np.full(20_000, 2e3)
    late[7000] = 2.5e6
    m = _measurement(late, longest_gap_ns=2.6e6)
    v = rig_check.verdict(m, _facts(), max_gap_s=1e-3)
    assert v.max_rate_hz is None and all(r.ends_overrun and not r.sustained for r in v.rates)
    assert all("OVERRUN" in line for line in v.lines)
    # the same stall under a 10 ms limit ends nothing; its one tick late is 1 in 20 000 (< 0.1 %)
    v10 = rig_check.verdict(m, _facts(), max_gap_s=10e-3)
    assert v10.max_rate_hz == max(rig_check.RATES_HZ)


def test_a_tail_of_late_ticks_limits_the_rate_and_the_hold():
    """0.5 % of ticks 150 us late: a period or more late at 10 kHz (100 us) but not at 5 kHz (200
    us); at 5 kHz a host 100 us away meets hold 1's 95 % (99.5 % of 100 + 2 us < 160 us) and no
    finer rate is sustained."""
    late = np.full(20_000, 2e3)
    late[::200] = 150e3  # 100 ticks of 20 000
    v = rig_check.verdict(_measurement(late, longest_gap_ns=250e3), _facts(), host_round_trip_us=100.0)
    by_rate = {r.rate_hz: r for r in v.rates}
    assert by_rate[10_000.0].overrun_share == pytest.approx(0.005) and not by_rate[10_000.0].sustained
    assert by_rate[5000.0].sustained and by_rate[5000.0].min_hold == 1
    assert by_rate[5000.0].holds[1] == pytest.approx(0.995)
    assert v.max_rate_hz == 5000.0


def test_hold_one_needs_the_round_trip_inside_the_command_wait():
    """At 10 kHz a host 90 us away misses hold 1 (90 + 2 us > 80 us, 0.8 of a period) on every
    step but makes hold 2 (< 180 us): the smallest hold that meets its goal is 2."""
    m = _measurement(np.full(20_000, 2e3), longest_gap_ns=105e3)
    r = rig_check.verdict_for_rate(10_000.0, m.tick_late_ns, m.longest_gap_ns, 1e-3, 90.0)
    assert r.holds[1] == 0.0 and r.holds[2] == 1.0 and r.min_hold == 2


def test_the_settings_named_are_the_ones_this_machine_lacks():
    f = _facts(may_fifo=False, fifo_max=0, hypervisor=True, governors=["powersave"], clocksource="kvm-clock",
               clocksources=["kvm-clock", "tsc"])
    settings = [s for s, _why in rig_check.improvements(f, loop_cpu=1, applied_fifo=False)]
    text = "\n".join(settings)
    assert "CAP_SYS_NICE" in settings[0]  # the most effective first: the policy itself
    assert "isolcpus=1 nohz_full=1 rcu_nocbs=1 irqaffinity=0" in text
    assert "preempt=full" in text and "clocksource=tsc" in text and "performance" in text
    assert "sched_autogroup_enabled=0" in text  # an ordinary loop's nice value needs it
    assert "sched_rt_runtime_us" not in text  # throttling matters to a SCHED_FIFO loop only
    tuned = _facts(preempt_model="PREEMPT_RT", preempt_rt=True, rt_runtime_us=-1, isolated=[1], nohz_full=[1],
                   version="#1 SMP PREEMPT_RT", governors=["performance"])
    assert rig_check.improvements(tuned, loop_cpu=1, applied_fifo=True) == []


def test_kernel_facts_are_read_from_proc_and_sys(tmp_path):
    files = {"proc/sys/kernel/version": "#1 SMP PREEMPT_RT Debian 6.1.0-rt",
             "proc/sys/kernel/sched_rt_runtime_us": "-1", "proc/sys/kernel/sched_rt_period_us": "1000000",
             "proc/sys/kernel/sched_autogroup_enabled": "0", "sys/devices/system/cpu/isolated": "2-3,5",
             "sys/devices/system/cpu/nohz_full": "3", "proc/cmdline": "isolcpus=2-3,5 nohz_full=3",
             "sys/devices/system/clocksource/clocksource0/current_clocksource": "tsc",
             "sys/devices/system/clocksource/clocksource0/available_clocksource": "tsc hpet acpi_pm",
             "proc/cpuinfo": "processor : 0\nflags : fpu sse2 hypervisor\n",
             "sys/devices/system/cpu/cpu0/cpufreq/scaling_governor": "performance"}
    for path, text in files.items():
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_text(text + "\n")
    f = rig_check.kernel_facts(tmp_path, probe=False)
    assert f.preempt_rt and f.preempt_model == "PREEMPT_RT" and not f.throttled and f.autogroup is False
    assert f.isolated == [2, 3, 5] and f.nohz_full == [3] and f.clocksource == "tsc" and f.hypervisor
    assert f.governors == ["performance"]
    assert rig_check.preempt_model("#1 SMP PREEMPT_DYNAMIC", None, "none voluntary (full) lazy") == (
        "full",
        False,
    )
    assert rig_check.preempt_model("#1 SMP PREEMPT_DYNAMIC", None, None) == ("dynamic", False)
    assert rig_check.preempt_model("#1 SMP", "1", None) == ("PREEMPT_RT", True)
    empty = rig_check.kernel_facts(tmp_path / "nothing", probe=False)  # nothing readable: throttled assumed
    assert empty.throttled and empty.isolated == []


def test_a_fifo_loop_rests_within_the_kernels_real_time_allowance(monkeypatch):
    """With throttling on (950 ms of each 1 s), a SCHED_FIFO loop spins through an episode that
    fits the allowance and rests after it: after 0.4 s of spinning, long enough that it spun at
    most RT_SHARE of what the kernel allows; an episode longer than RT_SPIN_LIMIT of it sleeps
    before each tick.  Throttling off: no rest, no sleep.  Time is injected."""
    monkeypatch.setattr(placement, "rt_allowance", lambda: (0.95, 1.0))
    pl = placement.Placement(-1, 0, 0)
    pl.loop_fifo = 50  # as if permitted; nothing is applied to a thread here
    assert pl.sleep_margin_for(0.4) == 0.0 and pl.sleep_margin_for(0.76) == 0.0
    assert pl.sleep_margin_for(0.8) == placement.SLEEP_MARGIN_S
    clock = [100.0]
    slept = []
    monkeypatch.setattr(placement.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(placement.time, "sleep", lambda s: slept.append(s))
    monkeypatch.setattr(placement.os, "sched_setscheduler", lambda *a: None)
    pl.loop_thread()
    clock[0] += 0.4
    pl.loop_done()
    clock[0] += 0.01
    pl.loop_thread()
    rest = 0.4 * (1.0 / (placement.RT_SHARE * 0.95) - 1.0)
    assert slept == [pytest.approx(rest - 0.01)]
    assert 0.4 / (0.4 + rest) == pytest.approx(placement.RT_SHARE * 0.95)
    monkeypatch.setattr(placement, "rt_allowance", lambda: None)
    slept.clear()
    clock[0] += 0.4
    pl.loop_done()
    pl.loop_thread()
    assert slept == [] and pl.sleep_margin_for(60.0) == 0.0


def test_two_cpus_say_that_a_host_here_has_no_cpu_of_its_own(monkeypatch):
    """With the loop pinned on a machine of two CPUs a host on it shares the other one with
    everything else: rig serve says so among what it could not apply; with three it is not said."""
    for cpus, said in (([0, 1], True), ([0, 1, 2], False)):
        monkeypatch.setattr(placement, "_allowed", lambda cpus=cpus: cpus)
        pl = placement.Placement(None, 0, 0)
        assert pl.pinned and pl.loop_cpu == cpus[-1]
        named = any(line.startswith("a CPU for a host on this machine") for line in pl.missing)
        assert named == said, pl.missing


def test_fifo_asked_by_name_is_refused_up_front_where_not_permitted(monkeypatch):
    monkeypatch.setattr(placement, "_may_fifo", lambda prio: "Operation not permitted")
    with pytest.raises(ValueError, match="loop_fifo = 50 needs root or CAP_SYS_NICE"):
        placement.Placement(None, 0, 50)
    auto = placement.Placement(None, 0, None)  # the default: applied where permitted, else said with its cost
    assert auto.loop_fifo == 0
    assert any(line.startswith("SCHED_FIFO (Operation not permitted") for line in auto.missing)
    monkeypatch.setattr(placement, "_may_fifo", lambda prio: None)
    assert placement.Placement(None, 0, None).loop_fifo == placement.AUTO_FIFO


@pytest.mark.skipif(len(getattr(os, "sched_getaffinity", lambda _: [0])(0)) < 2, reason="needs two CPUs")
def test_a_host_on_the_targets_machine_keeps_off_its_loop_cpu(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    before = os.sched_getaffinity(0)
    loop = max(before)
    remove = placement.publish_loop_cpu(45678, loop)
    try:
        assert placement.loop_cpu_of("127.0.0.1", 45678) == loop
        assert placement.loop_cpu_of("192.0.2.1", 45678) is None  # another machine's target
        assert placement.loop_cpu_of("127.0.0.1", 45679) is None  # no note for that port
        restore = placement.keep_off_loop_cpu("127.0.0.1", 45678)
        assert os.sched_getaffinity(0) == before - {loop}
        restore()
        assert os.sched_getaffinity(0) == before
    finally:
        remove()
        os.sched_setaffinity(0, before)
    assert placement.loop_cpu_of("127.0.0.1", 45678) is None  # removed with the target
    note = tmp_path / f"impact-env-rig-{os.getuid()}" / "45678.json"
    note.write_text(json.dumps({"pid": 2**22 + 12345, "loop_cpu": loop}))  # a target long gone
    assert placement.loop_cpu_of("127.0.0.1", 45678) is None


def test_the_measurement_records_what_it_paced():
    """The compiled pacing on this machine, briefly: its samples are lateness (>= 0), one per
    tick run, and the longest stretch is at least a period (no figure is asserted)."""
    from impact_env.rig.cycles import cached_ns_per_cycle

    pl = placement.Placement(-1, 0, 0)
    m = rig_check.measure(0.03, 10_000.0, pl, interval_us=1000.0)
    assert m.tick_late_ns.size == 200 and (m.tick_late_ns >= 0).all() and m.wakeup_ns.size == 10
    assert m.longest_gap_ns >= 1e5 * 0.99 and m.policy == "SCHED_OTHER" and m.cpu == -1
    assert cached_ns_per_cycle() > 0
    out = rig_check.report(m, rig_check.kernel_facts(probe=False), rig_check.verdict(m, _facts()))
    json.dumps(out)  # one JSON-able record
    assert set(out["tick_late_us"]) >= {"p50", "p99", "p99.9", "max", "longest_gap_us"}


def test_rig_check_prints_one_json_record_and_refuses_bad_options(capsys):
    """``impact-env rig check`` end to end, briefly (no figure asserted), and its bounds checked
    before any measurement."""
    from impact_env.cli.main import main

    assert main(["rig", "check", "--seconds", "0.06", "--loop-cpu", "-1", "--loop-fifo", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (
        out["policy"] == "SCHED_OTHER" and out["cpu"] == -1 and len(out["rates"]) == len(rig_check.RATES_HZ)
    )
    assert {"facts", "wakeup_us", "tick_late_us", "verdict", "improve"} <= set(out)
    for argv, what in ((["--seconds", "0"], "--seconds 0 s is out of range"),
                       (["--seconds", "601"], "--seconds 601 s is out of range"),
                       (["--rate", "0.5"], "--rate 0.5 Hz is out of range"),
                       (["--max-gap", "-1"], "--max-gap -1 ms is out of range")):
        assert main(["rig", "check", *argv]) == 2
        assert what in capsys.readouterr().err
