"""How the target's real-time loop keeps time on this machine, with only what the project sets.

    python scripts/bench_rig.py [--quick] [--label defaults] [--by-hand "SETTING ..."]
                                [--out docs/results/rig/bench-LABEL.json] [--doc docs/rig/timing.md]

The target runs as a separate process (``impact-env rig serve --virtual --log-dir TMP``) on
loopback, as on a rig with its host on the same machine, with the options a user gives it (none
beyond the log folder and ``--max-gap``; ``--serve-args`` adds more, and they are named in the
record): it applies what it is permitted to (``impact_env.rig.placement``: its loop pinned,
SCHED_FIFO where permitted, mlockall, the host kept off the loop's CPU) and says so at start; the
record keeps those lines.  The figures come from the episodes' logs.

1. Onboard, real time: the compiled pd-penetration law in episodes of 0.4 s until
   ``--onboard-ticks`` ticks: tick lateness (start minus deadline) p50 / p99 / p99.9 / max,
   overruns per 10^5 ticks, runs of 1 ms or more without a tick, how the episodes ended.
2. Host mode, real time, ``--episodes`` episodes a row, two hosts: ``ImpactCatchRig-v0`` stepped
   from Python (pd-penetration residual, actions drawn at random), and the pd-penetration law
   compiled on the host (``RigClient.run_policy``: each observation answered in the compiled call
   that read it); each at hold 4 and hold 1 alone, then with a CPU-bound process pinned to the
   loop's CPU (beside the loop), then under a flood of junk datagrams from a second process.
   Per row: of the commands the host sent, the share that acted within their own step; the steps
   the host did not answer (a host slower than the steps answers the newest observation); commands
   lost (sent, and in no episode's counters); RigTimeouts; the ends.
3. First episodes: ``--fresh`` targets started afresh, each one host-mode episode at hold 4: how
   many reached their horizon.

``--by-hand`` names kernel settings made by hand for the run (sysctl, boot parameters); the
record also keeps the kernel's real-time settings as found.  ``--doc`` rewrites the block between
``<!-- rig-bench:start -->`` and ``<!-- rig-bench:end -->`` of the rig's timing page from every
record in the folder of ``--out``, the defaults' first.  Wall-clock figures: they say what this
machine did under the load it had (recorded), not what a rig with an isolated core would.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from impact_env.policy.export import export_policy
from impact_env.rig import loopback
from impact_env.rig.host import RigClient, RigEnv
from impact_env.rig.log import list_episodes, read_episode
from impact_env.rig.placement import loop_cpu_of
from impact_env.rig.transport import RigTimeout
from impact_env.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def _file(log_dir: Path, episode: int, timeout_s: float = 30.0) -> Path:
    deadline = time.monotonic() + timeout_s
    while True:
        for p in list_episodes(log_dir):
            if p.name.endswith(f"_{episode:06d}.h5"):
                return p
        if time.monotonic() > deadline:
            raise TimeoutError(f"no log of episode {episode} in {log_dir}")
        time.sleep(0.02)


def onboard(addr: str, log_dir: Path, ticks: int, horizon: int) -> dict:
    """pd-penetration onboard in episodes of ``horizon`` ticks until ``ticks`` have passed."""
    scene = load_scene("rig")
    c = RigClient(addr)
    late, work, overruns, longest, ends, passed, long_gaps = [], [], 0, 0, {}, 0, 0
    try:
        pol = export_policy("pd-penetration", scene)
        seed = 1
        while passed < ticks:
            c.arm("onboard", seed, horizon, policy=pol)
            end = c.wait_end(timeout_s=60.0 + 3.0 * horizon / scene.control_rate)
            log = read_episode(_file(log_dir, end.episode))
            n = log.n_ticks - 1  # the last row is the final observation only
            late.append(log["lateness_ns"][1:n])
            work.append(log["compute_ns"][:n] / 1e3)
            overruns += int(log.meta.counters.get("overruns", 0))
            longest = max(longest, int(log["skipped_ticks"].max()))
            long_gaps += int((log["skipped_ticks"] >= 10).sum())  # 1 ms or more without a tick
            ends[log.meta.end_reason] = ends.get(log.meta.end_reason, 0) + 1
            passed += int(log["tick"][-1])
            seed += 1
    finally:
        c.close()
    lat, w = np.concatenate(late) / 1e3, np.concatenate(work)
    p = np.percentile(lat, [50, 99, 99.9])
    return {"ticks": passed, "rows": lat.size, "p": p, "max": float(lat.max()),
            "overruns_per_1e5": 1e5 * overruns / passed, "longest_skip": longest,
            "work": np.percentile(w, [50, 99]), "ends": ends, "episodes": seed - 1, "long_gaps": long_gaps}


def _count(tot: dict, log, hold: int, sent: int) -> None:
    """Add one episode's figures (from its log) to ``tot``."""
    c = log.meta.counters
    tot["sent"] += sent
    tot["accounted"] += c["commands_accepted"] + c["commands_late"]
    tot["unanswered"] += int(log["step"][-1]) - sent  # the steps the target observed, less those answered
    tick = log["tick"].astype(np.int64)[:-1]
    cstep = log["command_step"].astype(np.int64)[:-1]
    tot["own_step"] += np.unique(cstep[(cstep >= 0) & (tick // hold == cstep)]).size
    tot["late_ns"].append(log["lateness_ns"][1:-1])
    tot["ends"][log.meta.end_reason] = tot["ends"].get(log.meta.end_reason, 0) + 1


def _totals() -> dict:
    return {"sent": 0, "accounted": 0, "own_step": 0, "unanswered": 0, "timeouts": 0, "late_ns": [],
            "ends": {}}


def _finish(tot: dict) -> dict:
    lat = np.concatenate(tot.pop("late_ns")) / 1e3 if tot["late_ns"] else np.zeros(1)
    tot["lateness"] = np.percentile(lat, [50, 99, 99.9])
    return tot


def host_realtime(env: RigEnv, log_dir: Path, hold: int, episodes: int, seed0: int = 1000) -> dict:
    """``episodes`` episodes of ``env`` (hold ``hold``) with random actions; the figures of section 2."""
    rng = np.random.default_rng(0)
    tot = _totals()
    for k in range(episodes):
        sent = 0
        try:
            env.reset(seed=seed0 + k)
            while True:
                sent += 1
                _o, _r, te, tr, info = env.step(np.array([rng.uniform(-0.3, 0.3)], np.float32))
                if te or tr:
                    break
        except RigTimeout:
            tot["timeouts"] += 1
            tot["ends"]["RigTimeout"] = tot["ends"].get("RigTimeout", 0) + 1
            continue
        _count(tot, read_episode(_file(log_dir, env.client.episode)), hold, sent)
    return _finish(tot)


def host_compiled(client: RigClient, log_dir: Path, hold: int, episodes: int, seed0: int = 1000) -> dict:
    """The figures of section 2 for ``episodes`` episodes of the pd-penetration law compiled on
    the host (``RigClient.run_policy``), held ``hold`` ticks."""
    import dataclasses

    policy = dataclasses.replace(export_policy("pd-penetration", client.scene), hold_ticks=hold)
    n_steps = int(round(0.3 * client.scene.control_rate / hold))  # the scene's horizon, as the env's
    tot = _totals()
    for k in range(episodes):
        try:
            run = client.run_policy(policy, seed0 + k, n_steps)
        except RigTimeout:
            tot["timeouts"] += 1
            tot["ends"]["RigTimeout"] = tot["ends"].get("RigTimeout", 0) + 1
            continue
        _count(tot, read_episode(_file(log_dir, run.end.episode)), hold, int(np.isfinite(run.actions).sum()))
    return _finish(tot)


HOSTS = {"python": "ImpactCatchRig-v0, stepped from Python", "compiled": "the policy compiled on the host"}


def _host_row(host: str, what: str, hold: int, h: dict) -> dict:
    """One host-mode row of the record (``host``: a key of HOSTS)."""
    return {"host": host, "what": what, "hold": hold, "sent": h["sent"], "own_step": h["own_step"],
            "own_step_share": h["own_step"] / max(1, h["sent"]), "unanswered": h["unanswered"],
            "lost": h["sent"] - h["accounted"], "timeouts": h["timeouts"], "ends": h["ends"],
            "lateness_us": [round(float(x), 1) for x in h["lateness"]], "load": os.getloadavg()[0]}


def _print_host(r: dict) -> None:
    lp = r["lateness_us"]
    share = 100 * r["own_step_share"]
    print(f"| {r['host']} | {r['hold']} | {r['what']} | {r['sent']} | {r['own_step']} ({share:.1f} %) | "
          f"{r['unanswered']} | {r['lost']} | {r['timeouts']} | {lp[0]:.0f} / {lp[1]:.0f} / {lp[2]:.0f} | "
          f"{r['ends']} | {r['load']:.1f} |", flush=True)


def _recorded_hello(client: RigClient) -> bytes:
    """The host's HELLO as a sniffer on the wire would have it."""
    ep = client.endpoint
    sent: list[bytes] = []
    real = ep.send

    def send(data, addr=None):
        sent.append(bytes(data))
        return real(data, addr)

    ep.send = send
    try:
        client.hello()
    finally:
        ep.send = real
    return [d for d in sent if d[6] == 1][-1]


def _since_start(text: str) -> dict[str, int]:
    m = re.search(r"datagrams since start: (.*)", text)
    return {k: int(v) for k, v in re.findall(r"(\w+) (\d+)", m.group(1))} if m else {}


def _env(addr: str, hold: int) -> RigEnv:
    return RigEnv(addr, hold_ticks=hold, residual="pd-penetration", terminate_on_catch=False, timeout_s=0.1,
                  retries=20)


def host_row(host: str, what: str, addr: str, log_dir: Path, hold: int, episodes: int,
             seed0: int = 1000, started=None) -> dict:
    """One row of section 2 by ``host`` (a key of HOSTS); ``started(client)`` runs once its
    session is open (the flood's start)."""
    if host == "python":
        env = _env(addr, hold)
        try:
            if started is not None:
                started(env.client)
            return _host_row(host, what, hold, host_realtime(env, log_dir, hold, episodes, seed0))
        finally:
            env.close()
    client = RigClient(addr, timeout_s=0.1, retries=20)
    try:
        if started is not None:
            started(client)
        return _host_row(host, what, hold, host_compiled(client, log_dir, hold, episodes, seed0))
    finally:
        client.close()


def _flood_rows(addr: str, log_dir: Path, episodes: int, cpus: list[int]) -> tuple[list[dict], dict]:
    """Section 2's rows under a flood of junk datagrams (each host at hold 4 and hold 1), and the
    flood's own report."""
    FLOOD_WHAT = "a flood of junk datagrams"
    rows: list[dict] = []
    flood = None
    go = log_dir / "go"

    def start(client: RigClient) -> None:
        nonlocal flood
        if flood is not None:
            return
        hello = _recorded_hello(client)
        host, port = re.match(r"udp://([^:]+):(\d+)", addr).groups()
        flood = subprocess.Popen([sys.executable, "-c", loopback.FLOOD, host, port, hello.hex(), str(go),
                                  str(10**9), "600"], stdout=subprocess.PIPE, text=True)
        os.sched_setaffinity(flood.pid, {cpus[0]})  # an attacker on the network, not a load on the loop
        os.setpriority(os.PRIO_PROCESS, flood.pid, 19)
        assert flood.stdout.readline().strip() == "ready"
        go.touch()
        time.sleep(0.2)

    try:
        for host in HOSTS:
            for hold in (4, 1):
                rows.append(host_row(host, FLOOD_WHAT, addr, log_dir, hold, episodes, seed0=2000,
                                     started=start))
                _print_host(rows[-1])
        assert flood is not None
        go.unlink()  # the flood stops
        out, _ = flood.communicate(timeout=60)
        flood = None
        return rows, json.loads(out)
    finally:
        if flood is not None:
            flood.kill()
            flood.wait()


def first_episodes(n: int, serve: list[str]) -> dict:
    """``n`` targets started afresh, each one host-mode episode at hold 4 (random actions)."""
    ends: dict[str, int] = {}
    rng = np.random.default_rng(1)
    for k in range(n):
        proc, addr = loopback.serve(*serve)
        env = None
        try:
            env = _env(addr, 4)
            env.reset(seed=3000 + k)
            while True:
                *_, te, tr, info = env.step(np.array([rng.uniform(-0.3, 0.3)], np.float32))
                if te or tr:
                    break
            why = info.get("end_reason", "?")
        except RigTimeout:
            why = "RigTimeout"
        finally:
            if env is not None:
                env.close()
            loopback.stop(proc)
        ends[why] = ends.get(why, 0) + 1
    return {"targets": n, "horizon": ends.get("HORIZON", 0), "ends": ends}


def kernel_settings() -> dict:
    """The kernel's real-time settings as found (a record names them beside its figures)."""
    from impact_env.rig.check import kernel_facts

    f = kernel_facts(probe=False)
    return {"sched_rt_runtime_us": f.rt_runtime_us, "sched_autogroup_enabled": f.autogroup,
            "preempt": f.preempt_model, "isolated": f.isolated, "nohz_full": f.nohz_full,
            "clocksource": f.clocksource, "virtual_machine": f.hypervisor, "kernel": f.release}


TIMING_GOALS = [("alone", 4, 0.99), ("alone", 1, 0.95), ("a flood of junk datagrams", 4, 0.95)]
GOALS = [("commands lost (after the ones that came after their episode), all rows", "0"),
         ("RigTimeouts, all rows", "0"),
         ("first episodes reaching their horizon", "100 %")]


def goals(rec: dict) -> list[tuple[str, str, str, bool]]:
    """(goal, target, measured, met) for each of the rig's goals: the share of commands acting in
    their own step (TIMING_GOALS) for each host, then GOALS."""
    rows = {(r.get("host", "python"), r["what"], r["hold"]): r for r in rec["host"]}
    out = []
    for host in HOSTS:
        for what, hold, goal in TIMING_GOALS:
            r = rows.get((host, what, hold))
            if r is not None:
                where = "alone" if what == "alone" else "a flood"
                out.append((f"{HOSTS[host]}: hold {hold}, {where}: commands acting in their own step",
                            f">= {100 * goal:g} %", f"{100 * r['own_step_share']:.1f} %",
                            r["own_step_share"] >= goal))
    # a command that came after its episode had ended is in no episode's counters but in the
    # target's commands_after_end (printed when it stops): accounted for, not lost
    lost = sum(r["lost"] for r in rec["host"]) - rec.get("since_start", {}).get("commands_after_end", 0)
    timeouts = sum(r["timeouts"] for r in rec["host"])
    out.append((GOALS[0][0], GOALS[0][1], str(lost), lost == 0))
    out.append((GOALS[1][0], GOALS[1][1], str(timeouts), timeouts == 0))
    fe = rec.get("first_episodes")
    if fe and fe["targets"]:
        out.append((GOALS[2][0], GOALS[2][1], f"{fe['horizon']} of {fe['targets']}",
                    fe["horizon"] == fe["targets"]))
    return out


def render(records: list[dict]) -> str:
    """The timing page's block: one section per record, the defaults' first."""
    lines = []
    for rec in sorted(records, key=lambda r: (bool(r["by_hand"]), r["label"])):
        o = rec["onboard"]
        setup = ("only what the project sets (no setting made by hand)" if not rec["by_hand"] else
                 "with settings made by hand: " + ", ".join(f"`{s}`" for s in rec["by_hand"]))
        k = rec["kernel"]
        # the date, the CPU and the machine's load stay in the record, not on the page
        lines += [f"**{rec['label']}**: {setup}.  Written by `{rec['command']}` ({rec['cores']} CPUs, "
                  f"kernel {k['kernel']} ({k['preempt']} preemption"
                  f"{', a virtual machine' if k['virtual_machine'] else ''}), `sched_rt_runtime_us` "
                  f"{k['sched_rt_runtime_us']}, autogroup {'on' if k['sched_autogroup_enabled'] else 'off'}; "
                  f"the record `{rec['json']}` keeps the date, the CPU and the machine's load before and "
                  "after).  The target applied: "
                  + "; ".join(rec["applied"] or ["nothing"])
                  + (".  Not applied: " + "; ".join(rec["not_applied"]) if rec["not_applied"] else "")
                  + ".", "",
                  "| onboard ticks | lateness p50 / p99 / p99.9 / max us | overruns per 1e5 ticks | runs of "
                  "1 ms "
                  "or more | ends |", "|---|---|---|---|---|",
                  f"| {o['ticks']} | {o['p50_us']:.1f} / {o['p99_us']:.1f} / {o['p999_us']:.1f} / "
                  f"{o['max_us']:.0f} | "
                  f"{o['overruns_per_1e5']:.0f} | {o['long_gaps']} | {o['ends']} |", "",
                  "| host | hold | beside the loop | commands sent | acted in their own step "
                  "| steps not answered | in no episode's counters | RigTimeouts | ends |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rec["host"]:
            lines.append(f"| {HOSTS[r.get('host', 'python')]} | {r['hold']} | {r['what']} | {r['sent']} | "
                         f"{100 * r['own_step_share']:.1f} % | "
                         f"{r['unanswered']} | {r['lost']} | {r['timeouts']} | {r['ends']} |")
        lines += ["", "| goal | target | measured | met |", "|---|---|---|---|"]
        for name, target, measured, met in goals(rec):
            lines.append(f"| {name} | {target} | {measured} | {'yes' if met else '**no**'} |")
        lines.append("")
    return "\n".join(lines)


def write_doc(doc: Path, folder: Path) -> None:
    records = [json.loads(p.read_text()) for p in sorted(folder.glob("bench-*.json"))]
    page = doc.read_text()
    start, end = "<!-- rig-bench:start -->", "<!-- rig-bench:end -->"
    i, j = page.index(start), page.index(end)
    doc.write_text(page[:i] + start + "\n" + render(records) + page[j:])


def main() -> int:
    import platform

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=20, help="host-mode episodes per row (default 20)")
    ap.add_argument("--onboard-ticks", type=int, default=1_000_000, help="onboard ticks (default 1e6)")
    ap.add_argument("--fresh", type=int, default=5,
                    help="fresh targets for the first-episode row (default 5)")
    ap.add_argument("--max-gap-ms", type=float, default=1.0,
                    help="the target's --max-gap (default 1 ms, the target's own default)")
    ap.add_argument("--serve-args", default="", help="more rig serve options (named in the record)")
    ap.add_argument("--label", default="defaults", help="the record's name (default 'defaults')")
    ap.add_argument("--by-hand", nargs="*", default=[], metavar="SETTING",
                    help="kernel settings made by hand for this run, e.g. kernel.sched_rt_runtime_us=-1")
    ap.add_argument("--out", default=None, help="the JSON record (default docs/results/rig/bench-LABEL.json)")
    ap.add_argument("--doc", default=None,
                    help="rewrite the rig-bench block of this page (docs/rig/timing.md)")
    ap.add_argument("--quick", action="store_true",
                    help="3 episodes a row, 2e5 onboard ticks, 2 fresh targets")
    args = ap.parse_args()
    episodes = 3 if args.quick else args.episodes
    ticks = 200_000 if args.quick else args.onboard_ticks
    fresh = 2 if args.quick else args.fresh
    out_path = Path(args.out or ROOT / "docs" / "results" / "rig" / f"bench-{args.label}.json")
    cpus = sorted(os.sched_getaffinity(0))
    load_before = os.getloadavg()
    serve = ["--scene", "rig", "--max-gap", str(args.max_gap_ms), *args.serve_args.split()]
    kernel = kernel_settings()
    print(f"# bench_rig: {len(cpus)} CPUs, load average at start {_load()}; rig serve {' '.join(serve)}; "
          f"kernel: {kernel}; by hand: {args.by_hand or 'nothing'}\n")
    rec: dict = {"script": "scripts/bench_rig.py", "label": args.label, "by_hand": args.by_hand,
                 "command": " ".join(["python", "scripts/bench_rig.py", *sys.argv[1:]]),
                 "json": str(out_path.relative_to(ROOT)) if out_path.is_relative_to(ROOT) else str(out_path),
                 "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
                 "cpu": platform.processor() or platform.machine(), "cores": len(cpus),
                 "python": platform.python_version(), "kernel": kernel,
                 "serve": serve, "loadavg_before": [round(x, 2) for x in load_before], "host": []}
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = Path(tmp)
        rt, addr = loopback.serve(*serve, "--log-dir", str(log_dir))
        hog = None
        try:
            print("## 1. Onboard, real time, pd-penetration, episodes of 0.4 s\n")
            r = onboard(addr, log_dir, ticks, 4_000)
            rec["onboard"] = {"ticks": r["ticks"], "p50_us": r["p"][0], "p99_us": r["p"][1],
                              "p999_us": r["p"][2],
                              "max_us": r["max"], "overruns_per_1e5": r["overruns_per_1e5"],
                              "longest_skip": r["longest_skip"], "long_gaps": r["long_gaps"],
                              "ends": r["ends"]}
            print(json.dumps(rec["onboard"]), flush=True)
            print(f"\n## 2. Host mode, real time, two hosts, {episodes} episodes a row\n")
            print("| host | hold | beside the loop | commands sent | acted in their own step | "
                  "steps not answered | lost | RigTimeouts | lateness p50/p99/p99.9 us | ends | load |\n"
                  "|---|---|---|---|---|---|---|---|---|---|---|")
            loop_cpu = loop_cpu_of("127.0.0.1", int(addr.rsplit(":", 1)[1]))
            for what in ("alone", "a CPU-bound process on the loop's CPU"):
                if what != "alone":
                    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    os.sched_setaffinity(hog.pid, {cpus[-1] if loop_cpu is None else loop_cpu})
                for host in HOSTS:
                    for hold in (4, 1):
                        rec["host"].append(host_row(host, what, addr, log_dir, hold, episodes))
                        _print_host(rec["host"][-1])
                if hog is not None:
                    hog.kill()
                    hog.wait()
                    hog = None
            rows, report = _flood_rows(addr, log_dir, episodes, cpus)
            rec["host"] += rows
            rec["flood"] = report
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
            loopback.stop(rt)
        text, err = rt.stdout.read(), rt.stderr.read()
        rec["applied"] = re.findall(r"impact-env rig: applied: (.*)", err)
        rec["not_applied"] = re.findall(r"impact-env rig: not applied: (.*)", err)
        rec["start_check"] = re.findall(r"impact-env rig: (this machine, .*)", err)
        rec["since_start"] = _since_start(text)
    print(f"\n## 3. First episodes: {fresh} fresh targets, one host-mode episode each at hold 4\n",
          flush=True)
    rec["first_episodes"] = first_episodes(fresh, serve)
    print(json.dumps(rec["first_episodes"]))
    rec["loadavg_after"] = [round(x, 2) for x in os.getloadavg()]
    print("\n| goal | target | measured | met |\n|---|---|---|---|")
    for name, target, measured, met in goals(rec):
        print(f"| {name} | {target} | {measured} | {'yes' if met else 'no'} |")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(rec, indent=1, default=float) + "\n")
    print(f"\nrecord: {out_path}")
    if args.doc:
        write_doc(Path(args.doc), out_path.parent)
        print(f"block rewritten: {args.doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
