"""``impact-env rig serve | check | keygen | log | identify``: the real-time target, this machine's
fitness for it, session keys, the summary of an episode log, and the identification plan run on a
target."""

from __future__ import annotations

import json
import math
import os
import sys
import typing

from impact_env.cli.args import add_format_argument, add_scene_arguments, output_figure_file, scene_from_args
from impact_env.cli.identify import add_identify_arguments, cmd_rig_identify
from impact_env.config import ConfigError
from impact_env.rig.auth import KeyFileError, load_key, write_key
from impact_env.rig.cdriver import CDriver
from impact_env.rig.driver import RigDriver, VirtualRig
from impact_env.rig.errors import RigError
from impact_env.rig.flight_energy import summarize
from impact_env.rig.log import read_episode
from impact_env.rig.log_metrics import exact_metrics, has_truth
from impact_env.rig.log_plot import plot_log
from impact_env.rig.safety import OVERRUN, describe_status
from impact_env.rig.target import Target, TargetConfig
from impact_env.scene import load_scene


def add_arguments(p) -> None:
    """``rig``'s subcommands and their arguments on its subparser (:data:`impact_env.cli.main.COMMANDS`)."""
    rsub = p.add_subparsers(dest="rig_command", required=True)
    s = rsub.add_parser("serve", help="run the 10 kHz target until SIGTERM (prints a line with 'listening')")
    add_scene_arguments(s, default="rig")
    d = s.add_mutually_exclusive_group(required=True)
    d.add_argument("--virtual", action="store_true", help="drive a simulated rig (the driver built in)")
    d.add_argument("--driver", metavar="LIB.so|MODULE:CLASS",
                   help="drive a rig through a C driver (a shared library exporting impact_driver_open, "
                        "impact_env/deploy/rt/impact_driver.h: what real time needs) or a Python RigDriver "
                        "subclass (lock-step only); docs/rig/drivers.md")
    s.add_argument("--driver-config", default="", metavar="STRING",
                   help="passed to the C driver's impact_driver_open (its syntax is the driver's; the replay "
                        "driver's: 'READINGS.f64;COMMANDS.f64')")
    s.add_argument("--max-gap", type=float, default=1.0, metavar="MS",
                   help="real time: no tick run for longer than this ends the episode OVERRUN at 0 N "
                        "(default 1 ms)")
    s.add_argument("--command-wait", type=float, default=None, metavar="MS",
                   help="real-time host mode: a tick whose step's command has not come waits this long for it "
                        "before acting (default 0.8 of the control period: 0.08 ms at 10 kHz; 0: never)")
    s.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                   help="the CPU the real-time loop is pinned to, the target's Python threads going to the "
                        "others (default: the last CPU, with two or more; -1: no pinning)")
    s.add_argument("--loop-fifo", type=int, default=None, metavar="PRIO",
                   help="the loop thread's SCHED_FIFO priority (1-99; needs root, CAP_SYS_NICE or an rtprio "
                        "limit): no ordinary thread preempts it (default in real time: 50 where permitted, else "
                        "the normal policy, said at start; 0: the normal policy)")
    s.add_argument("--start-check", type=float, default=0.3, metavar="S",
                   help="real time: measure the loop's pacing this long at start and say what it costs here "
                        "(default 0.3 s; 0: no measurement; impact-env rig check measures at length)")
    s.add_argument("--loop-nice", type=int, default=0, metavar="N",
                   help="the loop thread's nice value, e.g. -10 (needs root or CAP_SYS_NICE; default 0)")
    s.add_argument("--max-horizon", type=float, default=60.0, metavar="S",
                   help="the longest episode an ARM may ask for (default 60 s); longer ones are refused")
    s.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: loopback only)")
    s.add_argument("--port", type=int, default=5600, help="UDP port (default 5600; 0: any free port)")
    s.add_argument("--lockstep", action="store_true",
                   help="advance a tick when its command is there (deterministic; tests), not on the clock")
    s.add_argument("--log-dir", metavar="DIR", help="write one HDF5 log per episode here")
    s.add_argument("--key", metavar="FILE",
                   help="the session key file (impact-env rig keygen FILE); every datagram is then "
                        "authenticated (HMAC-SHA256).  Without it only loopback peers are answered")
    s.add_argument("--session-timeout", type=float, default=60.0, metavar="S",
                   help="close an idle session whose host has been silent this long (default 60 s); until "
                        "then a HELLO from any other address is refused")
    s.add_argument("--seed", type=int, default=0,
                   help="added to every episode's seed (default 0: the drops ImpactCatch-v0 meets for the "
                        "same reset seeds)")
    s.add_argument("--physics", metavar="SCENE",
                   help="--virtual only: the virtual rig's hardware is this scene (preset or .toml) while the "
                        "target is told --scene: a rig that differs from its description, as a physical one "
                        "does (for trying identification and the mismatch map)")
    s.set_defaults(func=cmd_serve)
    c = rsub.add_parser("check", help="measure this machine's fitness for the real-time loop (wake-up latency "
                                      "as cyclictest does, the loop's own pacing, the kernel's settings) and say "
                                      "which rates and holds it sustains and what would improve them")
    c.add_argument("--seconds", type=float, default=6.0, metavar="S",
                   help="how long to measure (default 6 s: a third cyclictest's wake-ups, the rest the loop's pacing)")
    c.add_argument("--rate", type=float, default=10_000.0, metavar="HZ",
                   help="the tick rate the pacing runs at (default 10000 Hz: the rig scene's)")
    c.add_argument("--interval", type=float, default=1000.0, metavar="US",
                   help="cyclictest's wake-up interval (default 1000 us, cyclictest's own)")
    c.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                   help="the CPU to measure on (default: the one rig serve pins its loop to; -1: not pinned)")
    c.add_argument("--loop-fifo", type=int, default=None, metavar="PRIO",
                   help="the SCHED_FIFO priority to measure under (default: rig serve's, 50 where permitted; "
                        "0: the normal policy)")
    c.add_argument("--max-gap", type=float, default=1.0, metavar="MS",
                   help="rig serve's --max-gap the verdict judges against (default 1 ms)")
    c.add_argument("--host-round-trip", type=float, default=100.0, metavar="US",
                   help="the host's round trip the host-mode verdict assumes (default 100 us: a host on the "
                        "same machine or a direct link)")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.set_defaults(func=cmd_check)
    i = rsub.add_parser("identify", help="run the identification plan on a target (quiet, shaker-only and "
                                         "identification-drop episodes), then calibrate its scene to the logs")
    i.add_argument("--rig", required=True, metavar="udp://HOST:PORT", help="the target (impact-env rig serve)")
    i.add_argument("--out", required=True, metavar="DIR",
                   help="logs go to DIR/logs; the calibrated scene to DIR/identified.toml with DIR/report.md")
    i.add_argument("--key", metavar="FILE", default=None, help="the session key file the target was started with")
    i.add_argument("--quick", action="store_true", help="the short plan (shorter episodes, 3 drops): a first look")
    i.add_argument("--drops", type=int, default=None, help="identification drops (default 5; quick: 3)")
    i.add_argument("--seed", type=int, default=0, help="the episodes' seeds start here (default 0)")
    i.add_argument("--no-fit", action="store_true", help="record the logs only (fit later: impact-env identify)")
    i.add_argument("--force", action="store_true", help="add to a non-empty --out")
    add_identify_arguments(i)
    i.set_defaults(func=cmd_rig_identify)
    k = rsub.add_parser("keygen", help="write a new random session key file (32 bytes, hex, mode 0600)")
    k.add_argument("file", help="the key file to create (never overwritten)")
    k.set_defaults(func=cmd_keygen)
    g = rsub.add_parser("log", help="summarise an episode log with compare's metrics")
    g.add_argument("file", help="an episode's .h5 file (impact-env rig serve --log-dir)")
    g.add_argument("--plot", metavar="OUT.png", help="plot the raw sensors, the forces and the energy (the "
                                                     "suffix picks png, pdf or svg)")
    add_format_argument(g, default=None, what="--plot's")
    g.add_argument("--json", action="store_true", help="print one JSON object")
    g.set_defaults(func=cmd_log)


def cmd_serve(args) -> int:
    from pathlib import Path

    if not args.session_timeout > 0:
        raise ConfigError(f"--session-timeout {args.session_timeout} s must be > 0 s")
    if not 0 <= args.start_check <= 10:
        raise ConfigError(f"--start-check {args.start_check:g} s is out of range: 0 to 10 s "
                          "(impact-env rig check measures at length)")
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port} is out of range: 0 to 65535")
    if args.log_dir and Path(args.log_dir).exists() and not Path(args.log_dir).is_dir():
        raise ConfigError(f"--log-dir {args.log_dir!r} exists and is not a folder")

    try:
        key = load_key(args.key, "--key") if args.key else b""
    except KeyFileError as exc:
        raise ConfigError(str(exc)) from None
    scene = scene_from_args(args)
    if args.physics and not args.virtual:
        raise ConfigError("--physics describes a virtual rig's hardware: give it with --virtual")
    if args.virtual:
        driver = VirtualRig(scene, load_scene(args.physics) if args.physics else None)
    else:
        driver = load_driver(args.driver, scene, args.driver_config)
    kind = "virtual rig" if driver.virtual else f"driver {type(driver).__name__}"
    print(f"impact-env rig: compiling the target's kernels for scene {scene.name!r} ...", file=sys.stderr,
          flush=True)
    # SCHED_FIFO where permitted (None) serves real time; a lock-step loop has no deadline, so it
    # keeps the normal policy unless asked
    fifo = args.loop_fifo if args.loop_fifo is not None or not args.lockstep else 0
    try:
        target = Target(driver, f"udp://{args.host}:{args.port}",
                        TargetConfig(lockstep=args.lockstep, log_dir=Path(args.log_dir) if args.log_dir else None,
                                     seed_offset=args.seed, key=key, session_timeout_s=args.session_timeout,
                                     max_gap_s=args.max_gap / 1e3, max_horizon_s=args.max_horizon,
                                     command_wait_s=None if args.command_wait is None else args.command_wait / 1e3,
                                     loop_cpu=args.loop_cpu, loop_nice=args.loop_nice,
                                     loop_fifo=fifo))
    except ValueError as exc:
        driver.shutdown()
        option = any(name in str(exc) for name in ("command_wait_s", "loop_cpu", "loop_nice", "loop_fifo", "max_gap_s",
                                                      "max_horizon_s", "log_flush_s"))
        raise ConfigError(str(exc) if option or args.virtual else f"--driver {args.driver}: {exc}") from None
    target.install_signal_handlers()
    target.on_note = lambda text: print(f"impact-env rig: {text}", file=sys.stderr, flush=True)
    if key:
        print(f"impact-env rig: session key from {args.key}: every datagram is authenticated",
              file=sys.stderr,
              flush=True)
    else:
        print("impact-env rig: no --key: answering loopback peers only (127.0.0.0/8, ::1); give --key FILE "
              "to serve a network", file=sys.stderr, flush=True)
    remove_note = _apply_placement(target, args, scene.control_rate)
    print(f"impact-env rig: listening on {target.address} ({kind}, scene {scene.name}, "
          f"{'lock-step' if args.lockstep else 'real time'} at {scene.control_rate:g} Hz)", flush=True)
    target.serve()
    try:
        counts = {**target.lifetime_counts(), "commands_after_end": target.counters["commands_after_end"]}
        print(f"impact-env rig: datagrams since start: "
              f"{', '.join(f'{k} {v}' for k, v in counts.items() if v) or 'none'}", flush=True)
        c = target.counters
        print(f"impact-env rig: ticks since start: {c['overruns']} overruns, {c['skipped_ticks']} skipped ticks "
              f"({c['overrun_episodes']} episodes ended OVERRUN)", flush=True)
        print(f"impact-env rig: stopped after {target.counters['episodes']} episodes; shaker at 0 N",
              flush=True)
    except BrokenPipeError:  # whoever started us is gone; the shaker is at 0 N all the same
        pass
    remove_note()
    if target.signalled:
        # stopped by SIGTERM or SIGINT: the shaker is at 0 N, the driver shut down, every log
        # closed and fsynced; the interpreter's teardown (numba's and h5py's modules, the
        # threads) took seconds on a loaded machine, so the process ends here, at once
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (BrokenPipeError, ValueError):
                pass
        os._exit(0)
    return 0


def _apply_placement(target, args, rate_hz: float):
    """What the target applies of its placement (impact_env.rig.placement), printed with what it
    could not apply and, in real time, what that costs here: a short measurement of the loop's
    pacing as the loop will run (impact_env.rig.check).  Returns what removes the note that keeps a
    host on this machine off the loop's CPU."""
    from impact_env.rig.check import kernel_facts, measure, percentiles_us, verdict_for_rate
    from impact_env.rig.placement import publish_loop_cpu
    from impact_env.rig.transport import parse_address

    pl = target.placement
    say = lambda text: print(f"impact-env rig: {text}", file=sys.stderr, flush=True)  # noqa: E731
    remove = lambda: None  # noqa: E731
    if not args.lockstep:
        pl.lock_memory()
        if pl.pinned:
            remove = publish_loop_cpu(parse_address(target.address)[1], int(pl.loop_cpu))
            pl.applied.append(f"a host on this machine (ImpactCatchRig-v0, compare --rig) keeps off CPU "
                              f"{pl.loop_cpu} while its session lasts")
    say(pl.describe())
    for line in pl.applied:
        say(f"applied: {line}")
    for line in pl.missing:
        say(f"not applied: {line}")
    if args.lockstep or not args.start_check > 0:
        return remove
    m = measure(args.start_check, rate_hz, pl)
    facts = kernel_facts(probe=False)
    v = verdict_for_rate(rate_hz, m.tick_late_ns, m.longest_gap_ns, args.max_gap / 1e3, 100.0,
                         target.command_wait_s * rate_hz)
    late = percentiles_us(m.tick_late_ns)
    if v.sustained:
        what = "sustained onboard" + (f"; host mode from hold {v.min_hold} for a host 100 us away"
                                      if v.min_hold else "")
    elif v.ends_overrun:
        what = "NOT sustained (a stretch without a tick longer than --max-gap: episodes would end OVERRUN)"
    else:
        what = f"NOT sustained ({100 * v.overrun_share:.2f} % of ticks a period late)"
    say(f"this machine, {args.start_check:g} s paced as the loop ({m.policy}, CPU {m.cpu}): tick lateness "
        f"p99 "
        f"{late['p99']:.1f} us, max {late['max']:.0f} us, longest stretch without a tick "
        f"{m.longest_gap_ns / 1e3:.0f} us: {rate_hz:g} Hz {what}"
        + ("" if v.sustained and not pl.missing and not facts.hypervisor else
           "; impact-env rig check says what would improve it"))
    return remove


def cmd_check(args) -> int:
    """``impact-env rig check``: see :mod:`impact_env.rig.check`."""
    from impact_env.rig.check import kernel_facts, measure, percentiles_us, report, verdict
    from impact_env.rig.placement import Placement

    if not 0 < args.seconds <= 600:
        raise ConfigError(f"--seconds {args.seconds:g} s is out of range: more than 0 and at most 600 s")
    if not 1.0 <= args.rate <= 100_000.0:
        raise ConfigError(f"--rate {args.rate:g} Hz is out of range: 1 to 100000 Hz")
    if not 10.0 <= args.interval <= 1e6:
        raise ConfigError(f"--interval {args.interval:g} us is out of range: 10 to 1000000 us")
    if not 0 < args.max_gap <= 10_000:
        raise ConfigError(f"--max-gap {args.max_gap:g} ms is out of range: more than 0 and at most 10000 ms")
    if not 0 <= args.host_round_trip <= 1e6:
        raise ConfigError(f"--host-round-trip {args.host_round_trip:g} us is out of range: 0 to 1000000 us")
    try:
        pl = Placement(args.loop_cpu, 0, args.loop_fifo)
    except ValueError as exc:
        raise ConfigError(str(exc).replace("loop_cpu =", "--loop-cpu").replace("loop_fifo =", "--loop-fifo"))\
            from None
    facts = kernel_facts()
    if not args.json:
        cpu = pl.loop_cpu if pl.pinned else "(not pinned)"
        print(f"impact-env rig check: {args.seconds:g} s on CPU {cpu} "
              f"under {'SCHED_FIFO ' + str(pl.loop_fifo) if pl.loop_fifo else 'SCHED_OTHER'}, as rig serve "
              "runs its loop; no shaker is driven", flush=True)
    m = measure(args.seconds, args.rate, pl, args.interval)
    v = verdict(m, facts, args.max_gap / 1e3, args.host_round_trip)
    out = report(m, facts, v)
    if args.json:
        print(json.dumps(out))
        return 0
    f = facts
    print(f"kernel {f.release}: preemption {f.preempt_model}; real-time throttling "
          + (f"on ({f.rt_runtime_us} of {f.rt_period_us} us)" if f.throttled else "off")
          + f"; autogroup {'on' if f.autogroup else 'off'}; isolated CPUs {f.isolated or 'none'}; nohz_full "
          f"{f.nohz_full or 'none'}; clocksource {f.clocksource or '?'}"
          + ("; a virtual machine (hypervisor flag)" if f.hypervisor else ""))
    print(f"this process may: SCHED_FIFO {'yes (up to ' + str(f.fifo_max) + ')' if f.may_fifo else 'no'}, "
          f"mlockall {'yes' if f.may_mlock else 'no'}")
    w, t = percentiles_us(m.wakeup_ns), percentiles_us(m.tick_late_ns)
    print(f"wake-up latency (cyclictest: clock_nanosleep every {args.interval:g} us, {m.wakeup_ns.size} "
          "wake-ups): "
          f"p50 {w['p50']:.1f} us, p99 {w['p99']:.1f} us, p99.9 {w['p99.9']:.1f} us, max {w['max']:.1f} us")
    print(f"the loop's pacing ({args.rate:g} Hz, "
          + ("spinning" if not m.sleep_margin_s else
             f"sleeping to {m.sleep_margin_s * 1e6:g} us before each tick")
          + f", {m.tick_late_ns.size} ticks): lateness p50 {t['p50']:.1f} us, p99 {t['p99']:.1f} us, p99.9 "
          f"{t['p99.9']:.1f} us, max {t['max']:.1f} us; {int(m.tick_skipped.sum())} ticks skipped; longest "
          f"stretch without a tick {m.longest_gap_ns / 1e3:.0f} us")
    print("verdict:")
    for line in v.lines:
        print(f"  {line}")
    if v.improve:
        print("what would improve it (settings made by hand; name them beside any figure):")
        for setting, why in v.improve:
            print(f"  {setting}\n      {why}")
    return 0


def cmd_keygen(args) -> int:
    try:
        path = write_key(args.file)
    except FileExistsError:
        raise ConfigError(f"keygen: {args.file} exists; not overwritten (remove it first)") from None
    print(f"impact-env rig: wrote a 32-byte session key to {path} (mode 0600); give it to rig serve --key "
          "and "
          "to the host", flush=True)
    return 0


def load_driver(spec: str, scene, config: str = ""):
    """``LIB.so`` (a C driver, :class:`~impact_env.rig.cdriver.CDriver`, opened with ``config``)
    or ``MODULE:CLASS`` -> an instance of that :class:`~impact_env.rig.driver.RigDriver` subclass,
    constructed with ``scene``; ConfigError naming what is wrong before any device is opened."""
    import importlib

    if spec.endswith(".so") or spec.endswith(".dylib") or "/" in spec:
        try:
            return CDriver(spec, scene, config)
        except RigError as exc:
            raise ConfigError(str(exc)) from None
    module, sep, name = spec.partition(":")
    if not sep or not module or not name:
        raise ConfigError(f"--driver {spec!r}: expected LIB.so or MODULE:CLASS, e.g. ./nidaq.so or "
                          "myrig.driver:NiRig")
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        raise ConfigError(f"--driver {spec!r}: cannot import module {module!r} ({e}); is it on PYTHONPATH?") \
            from e
    cls = getattr(mod, name, None)
    if not (isinstance(cls, type) and issubclass(cls, RigDriver)):
        raise ConfigError(f"--driver {spec!r}: {module}.{name} is not a subclass of "
                          "impact_env.rig.driver.RigDriver")
    driver = typing.cast(typing.Any, cls)(scene)  # a driver class is constructed with the scene
    if driver.scene.control_rate != scene.control_rate:
        raise ConfigError(f"--driver {spec!r}: its scene's control rate ({driver.scene.control_rate:g} Hz) "
                          f"is not the served scene's ({scene.control_rate:g} Hz)")
    return driver


def cmd_log(args) -> int:
    from pathlib import Path

    import numpy as np

    if not Path(args.file).is_file():
        raise ConfigError(f"log file {args.file!r} not found")
    plot = output_figure_file(args.plot, args.format, "--plot") if args.plot else None  # before reading
    try:
        log = read_episode(args.file)
    except (OSError, KeyError) as exc:
        raise ConfigError(f"{args.file!r} is not a readable episode log: {exc}") from None
    est = summarize(log)
    out = {"file": args.file, "episode": log.meta.episode, "mode": log.meta.mode, "seed": log.meta.seed,
           "policy": log.meta.policy, "end_reason": log.meta.end_reason, "ticks": log.n_ticks,
           "counters": log.meta.counters, "estimated": {k: _num(v) for k, v in est.items()}}
    status = int(np.bitwise_or.reduce(log["status"])) if log.n_ticks else 0
    out["status_bits"] = describe_status(status)
    out["timing"] = timing_summary(log)
    if has_truth(log):
        out["true"] = {k: _num(v) for k, v in exact_metrics(log).items()}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{args.file}: episode {log.meta.episode} ({log.meta.mode} mode, seed {log.meta.seed}, "
              f"policy {log.meta.policy or 'from the host'}), {log.n_ticks} ticks, "
              f"ended by {log.meta.end_reason}; status seen: {', '.join(out['status_bits']) or 'none'}")
        keys = ("time_to_catch_s", "residual_energy_10ms", "residual_energy_50ms", "residual_energy_100ms",
                "energy_integral_ms", "exit_speed_ratio", "bounces", "peak_force_N", "rms_force_N",
                "contact_fraction", "saturation_time_s")
        print(f"  {'metric':24s} {'estimated (eq 4.5, ballistic)':>30s}"
              + ("  true (virtual rig)" if "true" in out else ""))
        for k in keys:
            line = f"  {k:24s} {_fmt(est.get(k)):>30s}"
            if "true" in out:
                line += f"  {_fmt(out['true'].get(k)):>18s}"
            print(line)
        t = out["timing"]
        print(f"  timing: {t['overruns']} overruns (rows flagged OVERRUN), {t['skipped_ticks']} ticks "
              "skipped "
              f"(the DAC held the last command), lateness p50 {t['lateness_p50_us']:.1f} us, "
              f"p99 {t['lateness_p99_us']:.1f} us, max {t['lateness_max_us']:.1f} us")
        if log.meta.mode == "host":
            c = log.meta.counters
            print(f"  commands (this episode): {c.get('commands_acted', 0)} acted, "
                  f"{c.get('commands_late', 0)} late, {c.get('commands_superseded', 0)} superseded, "
                  f"{c.get('commands_expired', 0)} expired "
                  f"(their step's ticks skipped), {c.get('commands_unused_at_end', 0)} unused at the end")
        print(f"  counters (this episode): "
              f"{', '.join(f'{k} {v}' for k, v in log.meta.counters.items() if v) or 'all 0'}")
    if plot is not None:
        plot_log(log, plot, est)
        if not args.json:
            print(f"  plot written to {plot}")
    return 0


def timing_summary(log) -> dict:
    """Overruns and skipped ticks of an episode log, from its rows (and its counters, which the
    target wrote: both are given so that a reader sees they agree), with the lateness percentiles."""
    import numpy as np

    n = log.n_ticks
    status = np.asarray(log["status"], dtype=np.int64) if n else np.zeros(0, np.int64)
    skipped = np.asarray(log["skipped_ticks"], dtype=np.int64) if n and "skipped_ticks" in log.columns \
        else np.zeros(0, np.int64)
    lat = np.asarray(log["lateness_ns"], dtype=float) / 1e3 if n else np.zeros(1)
    lat = lat if lat.size else np.zeros(1)
    return {"overruns": int(np.count_nonzero(status & OVERRUN)), "skipped_ticks": int(skipped.sum()),
            "counted_overruns": int(log.meta.counters.get("overruns", 0)),
            "counted_skipped_ticks": int(log.meta.counters.get("skipped_ticks", 0)),
            "lateness_p50_us": float(np.percentile(lat, 50)),
            "lateness_p99_us": float(np.percentile(lat, 99)),
            "lateness_max_us": float(lat.max())}


def _num(v):
    if isinstance(v, (bool, str)) or v is None:
        return v
    v = float(v)
    return None if not math.isfinite(v) else v


def _fmt(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return str(v)
    v = float(v)
    return "nan" if math.isnan(v) else ("inf" if math.isinf(v) else f"{v:.4g}")

