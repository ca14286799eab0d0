"""``impact-env rig check``: this machine's fitness for the target's real-time loop, measured
before any shaker is connected.

Two measurements, each in a thread placed and scheduled as ``rig serve`` places its loop
(:class:`impact_env.rig.placement.Placement`: pinned to the loop's CPU, ``SCHED_FIFO`` where the
process may), in compiled code that reads the clock as the loop does:

* **wake-up latency**, as rt-tests' cyclictest measures it (``cyclictest -m -n -p PRIO -i
  INTERVAL -a CPU``): the thread sleeps with ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)``
  to absolute deadlines ``t0 + k * interval`` and records ``now - deadline`` after each wake-up;
* **the loop's own pacing**: ticks at the scene's rate paced as the loop paces them (sleep to
  ``sleep_margin`` before the deadline where the loop sleeps, then spin on the CPU's cycle
  counter, :mod:`impact_env.rig.rtloop`), recording each tick's lateness, the ticks a late one
  would skip, and the longest stretch without a tick (the loop's ``max_gap``).

Beside them, what the kernel says of itself (:func:`kernel_facts`): the preemption model
(``/sys/kernel/realtime``, ``uname -v``, ``/sys/kernel/debug/sched/preempt`` where readable),
real-time throttling (``kernel.sched_rt_runtime_us``), autogroup
(``kernel.sched_autogroup_enabled``), isolated and ``nohz_full`` CPUs, the clocksource, a
hypervisor, and what this process may set (``SCHED_FIFO``, ``mlockall``).  :func:`verdict` turns
the lateness samples into the rates and holds the loop can sustain and names the settings that
would improve them; it is a pure function of its inputs (the tests give it samples).
"""

from __future__ import annotations

import ctypes
import os
import platform
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from impact_env._jit import jit
from impact_env.rig.cfunc import call_clock_gettime, call_clock_nanosleep, libc_address
from impact_env.rig.cycles import cached_ns_per_cycle, cycles

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
RATES_HZ = (1000.0, 2000.0, 5000.0, 10_000.0, 20_000.0)  # the rates the verdict judges
HOLDS = (1, 2, 4, 8, 16)
# the verdict's thresholds: a rate is sustained when at most this share of its ticks start a
# period or more late and no stretch without a tick reaches the loop's max_gap; a hold when at
# least this share of the host's commands act in their own step (the goals of the rig's figures)
MAX_OVERRUN_SHARE = 1e-3
OWN_STEP_GOAL = {1: 0.95}  # hold 1: 95 %; any other hold: 99 %
OWN_STEP_GOAL_DEFAULT = 0.99


# -- the measurements, in compiled code --------------------------------------------------------------------
@jit(inline="always")
def _now_ns(gettime, ts):
    call_clock_gettime(gettime, CLOCK_MONOTONIC, ts)
    return ts[0] * 1_000_000_000 + ts[1]


@jit(nogil=True)
def wakeup_latencies(gettime, nanosleep, interval_ns, out_ns):
    """cyclictest's loop: sleep to ``t0 + k * interval_ns`` (absolute), record ``now - deadline``
    (ns) in ``out_ns[k]`` for every k.  ``gettime``, ``nanosleep``: libc's addresses."""
    ts = np.zeros(2, np.int64)
    t0 = _now_ns(gettime, ts) + interval_ns
    for k in range(out_ns.shape[0]):
        dl = t0 + k * interval_ns
        ts[0] = dl // 1_000_000_000
        ts[1] = dl % 1_000_000_000
        call_clock_nanosleep(nanosleep, CLOCK_MONOTONIC, TIMER_ABSTIME, ts)
        out_ns[k] = _now_ns(gettime, ts) - dl


@jit(nogil=True)
def pace_ticks(cycles_per_tick, ns_per_cycle, sleep_margin_cycles, gettime, nanosleep, late_ns, skipped):
    """Ticks paced as the loop paces them (module doc): ``late_ns[i]`` the i-th tick run's start
    minus the deadline it waited for (ns), ``skipped[i]`` the ticks passed over with it (the loop
    skips the ticks that cannot run on time and runs the one that is due).  Returns (ticks run,
    the longest stretch without a tick, ns)."""
    ts = np.zeros(2, np.int64)
    c_ref, n_ref = float(cycles()), float(_now_ns(gettime, ts))
    t0 = float(cycles()) + cycles_per_tick
    m = 0
    prev = -1.0
    longest = 0.0
    n = late_ns.shape[0]
    for i in range(n):
        dl = t0 + m * cycles_per_tick
        now = float(cycles())
        if sleep_margin_cycles > 0.0 and dl - now > sleep_margin_cycles:
            t = np.int64(n_ref + (dl - sleep_margin_cycles - c_ref) * ns_per_cycle)
            ts[0] = t // 1_000_000_000
            ts[1] = t % 1_000_000_000
            call_clock_nanosleep(nanosleep, CLOCK_MONOTONIC, TIMER_ABSTIME, ts)
            now = float(cycles())
        while now < dl:
            now = float(cycles())
        late = now - dl
        k = int(late // cycles_per_tick)
        skipped[i] = k
        m += k
        late_ns[i] = late * ns_per_cycle
        if prev >= 0.0 and now - prev > longest:
            longest = now - prev
        prev = now
        m += 1
    return n, longest * ns_per_cycle


# -- what the kernel says ------------------------------------------------------------------------------------
def _read(root: Path, path: str) -> str | None:
    try:
        return (root / path.lstrip("/")).read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None


def _int(text: str | None) -> int | None:
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def _cpu_list(text: str | None) -> list[int]:
    """``0-2,5`` -> [0, 1, 2, 5] (the kernel's CPU list format)."""
    out: list[int] = []
    for part in (text or "").split(","):
        part = part.strip()
        if not part:
            continue
        lo, _, hi = part.partition("-")
        try:
            out += list(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            return []
    return out


@dataclass
class KernelFacts:
    """What the kernel and this process say of real-time scheduling (see :func:`kernel_facts`)."""

    release: str = ""
    version: str = ""
    preempt_model: str = "unknown"  # PREEMPT_RT, full, voluntary, none, dynamic (the model not readable)
    preempt_rt: bool = False
    rt_runtime_us: int | None = None  # kernel.sched_rt_runtime_us (-1: no real-time throttling)
    rt_period_us: int | None = None
    autogroup: bool | None = None  # kernel.sched_autogroup_enabled
    isolated: list[int] = field(default_factory=list)  # /sys/devices/system/cpu/isolated
    nohz_full: list[int] = field(default_factory=list)
    cmdline: str = ""
    clocksource: str = ""
    clocksources: list[str] = field(default_factory=list)
    hypervisor: bool = False
    governors: list[str] = field(default_factory=list)  # cpufreq scaling governors seen
    cpus: list[int] = field(default_factory=list)  # the CPUs this process may run on
    may_fifo: bool = False  # SCHED_FIFO permitted (root, CAP_SYS_NICE or RLIMIT_RTPRIO)
    fifo_max: int = 0  # the highest SCHED_FIFO priority permitted
    may_mlock: bool = False  # mlockall permitted

    @property
    def throttled(self) -> bool:
        return self.rt_runtime_us is None or self.rt_runtime_us != -1


def preempt_model(version: str, realtime: str | None, debug_preempt: str | None) -> tuple[str, bool]:
    """The preemption model from ``uname -v``, ``/sys/kernel/realtime`` and, on a
    ``PREEMPT_DYNAMIC`` kernel, ``/sys/kernel/debug/sched/preempt`` (the model in parentheses:
    ``none voluntary (full) lazy``); (model, PREEMPT_RT)."""
    rt = realtime == "1" or "PREEMPT_RT" in version
    if rt:
        return "PREEMPT_RT", True
    if debug_preempt and "(" in debug_preempt:
        return debug_preempt.split("(", 1)[1].split(")", 1)[0], False
    if "PREEMPT_DYNAMIC" in version:
        return "dynamic", False
    if "PREEMPT" in version.split():
        return "full", False
    return "voluntary or none", False


def fifo_permitted() -> tuple[bool, int]:
    """(may this process's threads use SCHED_FIFO, the highest priority it may use), asked by
    trying it on this thread and setting it back."""
    if not hasattr(os, "sched_setscheduler"):
        return False, 0
    tid = threading.get_native_id()
    try:
        was = os.sched_getscheduler(tid)
        param = os.sched_getparam(tid)
    except OSError:
        return False, 0
    best = 0
    for prio in (os.sched_get_priority_max(os.SCHED_FIFO), 50, 1):
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(prio))
        except OSError:
            continue
        best = prio
        break
    if best:
        os.sched_setscheduler(tid, was, param)
    return best > 0, best


MCL_CURRENT, MCL_FUTURE = 1, 2


def mlock_permitted() -> bool:
    """Whether ``mlockall`` is permitted here (tried and undone)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(MCL_CURRENT) != 0:
            return False
        libc.munlockall()
        return True
    except (OSError, AttributeError):
        return False


def kernel_facts(root: Path = Path("/"), probe: bool = True) -> KernelFacts:
    """What ``root``'s /proc and /sys say (``root`` other than / for tests), and with ``probe``
    what this process may set (SCHED_FIFO, mlockall: tried and undone)."""
    uname = platform.uname()
    f = KernelFacts(release=uname.release, version=uname.version)
    version = _read(root, "/proc/sys/kernel/version") or uname.version
    f.version = version
    f.preempt_model, f.preempt_rt = preempt_model(version, _read(root, "/sys/kernel/realtime"),
                                                  _read(root, "/sys/kernel/debug/sched/preempt"))
    f.rt_runtime_us = _int(_read(root, "/proc/sys/kernel/sched_rt_runtime_us"))
    f.rt_period_us = _int(_read(root, "/proc/sys/kernel/sched_rt_period_us"))
    ag = _int(_read(root, "/proc/sys/kernel/sched_autogroup_enabled"))
    f.autogroup = None if ag is None else bool(ag)
    f.isolated = _cpu_list(_read(root, "/sys/devices/system/cpu/isolated"))
    f.nohz_full = _cpu_list(_read(root, "/sys/devices/system/cpu/nohz_full"))
    f.cmdline = _read(root, "/proc/cmdline") or ""
    f.clocksource = _read(root, "/sys/devices/system/clocksource/clocksource0/current_clocksource") or ""
    f.clocksources = (_read(root, "/sys/devices/system/clocksource/clocksource0/available_clocksource")
                      or "").split()
    cpuinfo = _read(root, "/proc/cpuinfo") or ""
    f.hypervisor = any(line.startswith("flags") and " hypervisor" in line for line in cpuinfo.splitlines())
    cpu_dir = root / "sys/devices/system/cpu"
    govs = set()
    for gov in sorted(cpu_dir.glob("cpu[0-9]*/cpufreq/scaling_governor")):
        g = _read(root, "/" + str(gov.relative_to(root)))
        if g:
            govs.add(g)
    f.governors = sorted(govs)
    try:
        f.cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        f.cpus = []
    if probe:
        f.may_fifo, f.fifo_max = fifo_permitted()
        f.may_mlock = mlock_permitted()
    return f


# -- the measurement, placed as the loop ------------------------------------------------------------------
@dataclass
class Measurement:
    """Lateness samples of the two measurements (ns), how they were taken, and the longest
    stretch without a tick of the pacing one."""

    wakeup_ns: np.ndarray
    tick_late_ns: np.ndarray
    tick_skipped: np.ndarray
    longest_gap_ns: float
    rate_hz: float
    interval_ns: int
    cpu: int  # -1: not pinned
    policy: str  # "SCHED_FIFO 50", "SCHED_OTHER"
    sleep_margin_s: float  # the pacing's sleep margin (0: it spins)


def measure(seconds: float, rate_hz: float, placement, interval_us: float = 1000.0,
            episode_s: float = 0.4) -> Measurement:
    """``seconds`` of measurement in a thread placed by ``placement`` (its loop CPU and
    scheduling): a third of it cyclictest's wake-up latency at ``interval_us``, the rest the loop's
    pacing at ``rate_hz`` in episodes of ``episode_s``, with the rest between them that the loop
    takes (:meth:`impact_env.rig.placement.Placement.loop_thread`)."""
    nspc = cached_ns_per_cycle()
    gettime, nanosleep = libc_address("clock_gettime"), libc_address("clock_nanosleep")
    interval_ns = int(interval_us * 1e3)
    wake = np.zeros(max(1, int(seconds / 3 * 1e9 / interval_ns)), np.int64)
    n_ticks = max(1, int(seconds * 2 / 3 * rate_hz))
    late = np.zeros(n_ticks, np.float64)
    skipped = np.zeros(n_ticks, np.int64)
    cpt = 1e9 / rate_hz / nspc
    margin = placement.sleep_margin_for(episode_s) * 1e9 / nspc
    # compiled (or loaded) before the measured thread starts
    wakeup_latencies(gettime, nanosleep, 1000, np.zeros(1, np.int64))
    pace_ticks(cpt, nspc, margin, gettime, nanosleep, np.zeros(1), np.zeros(1, np.int64))
    out: list = []
    err: list = []

    chunk = max(1, int(episode_s * rate_hz))

    def run():
        try:
            placement.loop_thread()
            wakeup_latencies(gettime, nanosleep, interval_ns, wake)
            longest = 0.0
            for a in range(0, n_ticks, chunk):  # episode by episode, resting between them as the loop does
                if a > 0:
                    placement.loop_thread()
                b = min(n_ticks, a + chunk)
                _n, gap = pace_ticks(cpt, nspc, margin, gettime, nanosleep, late[a:b], skipped[a:b])
                placement.loop_done()
                longest = max(longest, gap)
            out.append(longest)
        except BaseException as exc:  # re-raised in the caller's thread
            err.append(exc)

    th = threading.Thread(target=run, name="rig-check", daemon=True)
    th.start()
    th.join()
    if err:
        raise err[0]
    policy = f"SCHED_FIFO {placement.loop_fifo}" if placement.loop_fifo else "SCHED_OTHER"
    return Measurement(wake, late, skipped, float(out[0]), float(rate_hz), interval_ns,
                       int(placement.loop_cpu) if placement.pinned else -1, policy,
                       placement.sleep_margin_for(episode_s))


# -- the verdict ------------------------------------------------------------------------------------------
def percentiles_us(x_ns: np.ndarray) -> dict[str, float]:
    x = np.asarray(x_ns, dtype=np.float64) / 1e3
    if x.size == 0:
        return {"p50": float("nan"), "p99": float("nan"), "p99.9": float("nan"), "max": float("nan")}
    p50, p99, p999 = np.percentile(x, [50.0, 99.0, 99.9])
    return {"p50": float(p50), "p99": float(p99), "p99.9": float(p999), "max": float(x.max())}


@dataclass
class RateVerdict:
    rate_hz: float
    overrun_share: float  # of ticks starting a period or more late
    ends_overrun: bool  # a stretch without a tick reached max_gap: an episode would end OVERRUN
    sustained: bool
    holds: dict[int, float]  # host mode: hold -> share of the host's commands acting in their own step
    min_hold: int | None  # the smallest hold that meets its goal (None: none)


def verdict_for_rate(rate_hz: float, lateness_ns: np.ndarray, longest_gap_ns: float, max_gap_s: float,
                     host_round_trip_us: float, command_wait: float = 0.8) -> RateVerdict:
    """Whether the loop sustains ``rate_hz`` given tick lateness samples (ns) of its pacing and the
    longest stretch without a tick (ns): at most :data:`MAX_OVERRUN_SHARE` of ticks a period or
    more late, and no stretch of ``max_gap_s`` or more (the target ends such an episode OVERRUN).
    Host mode at hold H: a step's command, sent when the step's observation leaves (its first
    tick's start) and back one round trip later, acts in its own step when it arrives before the
    step's last tick has waited ``command_wait`` of its period: ``late + round trip < (H - 1 +
    command_wait) T``; the share of samples for which that holds, per hold."""
    period_ns = 1e9 / rate_hz
    late = np.asarray(lateness_ns, dtype=np.float64)
    share = float(np.mean(late >= period_ns)) if late.size else 1.0
    ends = longest_gap_ns >= max_gap_s * 1e9
    sustained = share <= MAX_OVERRUN_SHARE and not ends
    holds: dict[int, float] = {}
    min_hold = None
    for h in HOLDS:
        in_step = late + host_round_trip_us * 1e3 < (h - 1 + command_wait) * period_ns
        ok = float(np.mean(in_step)) if late.size else 0.0
        holds[h] = ok
        if min_hold is None and sustained and ok >= OWN_STEP_GOAL.get(h, OWN_STEP_GOAL_DEFAULT):
            min_hold = h
    return RateVerdict(rate_hz, share, ends, sustained, holds, min_hold)


def improvements(f: KernelFacts, loop_cpu: int, applied_fifo: bool) -> list[tuple[str, str]]:
    """(setting, what it does) for each setting this machine lacks, most effective first; each a
    command or a kernel parameter a user sets by hand (none is set by the project)."""
    out: list[tuple[str, str]] = []
    if not f.may_fifo:
        out.append(("run the target as root, or give it CAP_SYS_NICE (sudo setcap "
                    "cap_sys_nice,cap_ipc_lock+ep "
                    "$(readlink -f $(command -v python3))), or an rtprio limit (/etc/security/limits.conf: "
                    "USER - rtprio 99, USER - memlock unlimited)",
                    "the loop then runs under SCHED_FIFO: no ordinary process preempts it"))
    if f.throttled and (f.may_fifo or applied_fifo):
        out.append(("sysctl -w kernel.sched_rt_runtime_us=-1",
                    "real-time throttling off: the SCHED_FIFO loop needs no rest between episodes and spins "
                    "through episodes of any length instead of sleeping before each tick (a runaway "
                    "real-time thread can then hold its CPU for good)"))
    if loop_cpu >= 0 and loop_cpu not in f.isolated:
        out.append((f"kernel command line: isolcpus={loop_cpu} nohz_full={loop_cpu} rcu_nocbs={loop_cpu} "
                    "irqaffinity=" + ",".join(str(c) for c in f.cpus if c != loop_cpu),
                    f"CPU {loop_cpu} kept for the loop: no other process, timer tick, RCU callback or "
                    "interrupt is put there"))
    if not f.preempt_rt:
        if f.preempt_model != "full" and "PREEMPT_DYNAMIC" in f.version:
            out.append(("kernel command line: preempt=full (this kernel is PREEMPT_DYNAMIC), or a PREEMPT_RT "
                        "kernel (Debian: linux-image-rt-amd64; Ubuntu: ubuntu-pro's realtime kernel)",
                        "the kernel's own sections become preemptible: shorter wake-up tails"))
        else:
            out.append(("a PREEMPT_RT kernel (Debian: linux-image-rt-amd64; Ubuntu: ubuntu-pro's realtime "
                        "kernel)", "bounds the kernel's own latencies (tens of us on bare metal)"))
    if f.autogroup and not (f.may_fifo or applied_fifo):
        out.append(("sysctl -w kernel.sched_autogroup_enabled=0",
                    "nice values then order the loop against processes of other sessions (--loop-nice)"))
    if f.clocksource and f.clocksource != "tsc" and "tsc" in f.clocksources:
        out.append(("kernel command line: clocksource=tsc tsc=reliable",
                    f"the TSC instead of {f.clocksource}: cheaper clock reads"))
    if any(g != "performance" for g in f.governors):
        out.append(("cpupower frequency-set -g performance",
                    "no frequency changes under the loop (governor now: " + ", ".join(f.governors) + ")"))
    if f.hypervisor:
        out.append(("bare metal, or a vCPU pinned to a host core of its own",
                    "a virtual machine's vCPU is descheduled by the hypervisor for milliseconds at times: "
                    "no setting inside the guest removes that"))
    return out


@dataclass
class Verdict:
    rates: list[RateVerdict]
    max_rate_hz: float | None  # the highest rate sustained (None: none of RATES_HZ)
    lines: list[str]  # what rig check prints as its verdict
    improve: list[tuple[str, str]]


def verdict(m: Measurement, f: KernelFacts, max_gap_s: float = 1e-3, host_round_trip_us: float = 100.0,
            command_wait: float = 0.8) -> Verdict:
    """The rates of :data:`RATES_HZ` the loop sustains on these samples, the smallest hold that
    meets its goal at each, and the settings that would improve them (:func:`improvements`)."""
    rates = [verdict_for_rate(r, m.tick_late_ns, m.longest_gap_ns, max_gap_s, host_round_trip_us,
                              command_wait) for r in RATES_HZ]
    ok = [r for r in rates if r.sustained]
    best = max((r.rate_hz for r in ok), default=None)
    lines = []
    for r in rates:
        khz = f"{r.rate_hz / 1e3:g} kHz"
        if not r.sustained:
            why = (f"a stretch of {m.longest_gap_ns / 1e6:.2f} ms without a tick (the target's limit "
                   f"{max_gap_s * 1e3:g} ms) would end an episode OVERRUN" if r.ends_overrun else
                   f"{100 * r.overrun_share:.2f} % of ticks start a period or more late (limit "
                   f"{100 * MAX_OVERRUN_SHARE:g} %)")
            lines.append(f"{khz}: not sustained: {why}")
        else:
            host = (f"host mode from hold {r.min_hold} ({100 * r.holds[r.min_hold]:.1f} % of commands in "
                    f"their own step for a host {host_round_trip_us:g} us away)"
                    if r.min_hold is not None else
                    f"host mode at no hold up to {HOLDS[-1]} (a host {host_round_trip_us:g} us away)")
            lines.append(f"{khz}: sustained onboard ({100 * r.overrun_share:.3f} % of ticks late); {host}")
    return Verdict(rates, best, lines, improvements(f, m.cpu, m.policy.startswith("SCHED_FIFO")))


def report(m: Measurement, f: KernelFacts, v: Verdict) -> dict:
    """One JSON-able record of the check."""
    return {"facts": asdict(f), "policy": m.policy, "cpu": m.cpu, "sleep_margin_us": m.sleep_margin_s * 1e6,
            "wakeup_us": {**percentiles_us(m.wakeup_ns), "samples": int(m.wakeup_ns.size),
                          "interval_us": m.interval_ns / 1e3},
            "tick_late_us": {**percentiles_us(m.tick_late_ns), "ticks": int(m.tick_late_ns.size),
                             "rate_hz": m.rate_hz, "skipped": int(m.tick_skipped.sum()),
                             "longest_gap_us": m.longest_gap_ns / 1e3},
            "rates": [asdict(r) for r in v.rates], "max_rate_hz": v.max_rate_hz,
            "verdict": v.lines, "improve": [{"setting": s, "why": w} for s, w in v.improve],
            "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime())}
