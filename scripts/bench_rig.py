"""How the target's compiled real-time core keeps time on this machine (issue 25's figures).

    python scripts/bench_rig.py [--episodes 20] [--onboard-ticks 1000000] [--loop-fifo 50] [--quick]

The target runs as a separate process (``impact-env rig serve --virtual --log-dir TMP``) on
loopback, as on a rig with its host on the same network; its real-time loop is pinned to the
last CPU (``impact_env.rig.placement``), and this process, the host, to the other CPUs, as
docs/rig/loop.md tells a host on the target's machine to be.  The figures come from the episodes'
logs, read from the target's log folder.

1. Onboard, real time: the compiled pd-penetration law in episodes of 10 s (10^5 ticks) until
   ``--onboard-ticks`` ticks (default 10^6): tick lateness (start minus deadline) p50 / p99 /
   p99.9 / max, overruns (rows flagged OVERRUN) per 10^5 ticks, the longest run of skipped ticks
   and the runs of 10 or more (1 ms without a tick: the target's default ``--max-gap`` ends an
   episode OVERRUN at such a gap; pass ``--max-gap-ms 1000`` to count them without ending it),
   the episodes' ends, and the tick's work (read, front end, policy, safety, the virtual rig's
   hardware stage, log row) p50 / p99.
2. Host mode, real time: ``ImpactCatchRig-v0`` (pd-penetration residual, actions drawn at
   random), ``--episodes`` episodes each at hold 4 and hold 1, first alone, then with a CPU-bound
   process of the bench's own pinned to CPU 0 (the host's): of the commands the host sent, the
   share that acted within their own step (a row of one of the step's ticks driven by the
   step's command), the steps whose observation the host never answered (it was answering a
   newer one), commands lost (sent, and in no episode's counters: not accepted, not late; the
   ones that came after their episode's end are the target's ``commands_after_end``),
   RigTimeouts, tick lateness p50 / p99 / p99.9 and the wall time of an episode.
3. The flood: hold 4, ``--episodes`` episodes while a process of the bench's own (pinned to CPU
   0, nice 19: an attacker on the network, not a load on the host) sends junk as fast as it can
   (a quarter each: the host's HELLO replayed, bad tags, bad magic, truncated frames); the same
   command figures, the datagrams sent and how the target accounted for them.

Wall-clock figures of a shared machine without a real-time kernel: they say what this machine
does under the load it had (the 1-minute load average is printed with them), not what a rig
controller with an isolated core would.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from rig_helpers import FLOOD, start_target, stop  # noqa: E402

from impact_env.policy.export import export_policy  # noqa: E402
from impact_env.rig.host import RigClient, RigEnv  # noqa: E402
from impact_env.rig.log import list_episodes, read_episode  # noqa: E402
from impact_env.rig.transport import RigTimeout  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402


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


def host_realtime(env: RigEnv, log_dir: Path, hold: int, episodes: int, seed0: int = 1000) -> dict:
    """``episodes`` episodes of ``env`` (hold ``hold``) with random actions; the figures of section 2."""
    rng = np.random.default_rng(0)
    tot = {"sent": 0, "accounted": 0, "own_step": 0, "unanswered": 0, "timeouts": 0}
    late_ns, wall, ends = [], [], {}
    for k in range(episodes):
        sent = 0
        t0 = time.perf_counter()
        try:
            env.reset(seed=seed0 + k)
            while True:
                sent += 1
                _o, _r, te, tr, info = env.step(np.array([rng.uniform(-0.3, 0.3)], np.float32))
                if te or tr:
                    break
        except RigTimeout:
            tot["timeouts"] += 1
            ends["RigTimeout"] = ends.get("RigTimeout", 0) + 1
            continue
        wall.append(time.perf_counter() - t0)
        why = info.get("end_reason", "?")
        ends[why] = ends.get(why, 0) + 1
        log = read_episode(_file(log_dir, env.client.episode))
        c = log.meta.counters
        tot["sent"] += sent
        tot["accounted"] += c["commands_accepted"] + c["commands_late"]
        tot["unanswered"] += int(log["step"][-1]) - sent  # the steps the target observed, less those answered
        tick = log["tick"].astype(np.int64)[:-1]
        cstep = log["command_step"].astype(np.int64)[:-1]
        tot["own_step"] += np.unique(cstep[(cstep >= 0) & (tick // hold == cstep)]).size
        late_ns.append(log["lateness_ns"][1:-1])
    lat = np.concatenate(late_ns) / 1e3 if late_ns else np.zeros(1)
    tot["lateness"] = np.percentile(lat, [50, 99, 99.9])
    tot["wall"] = np.percentile(wall, [50, 100]) if wall else np.zeros(2)
    tot["ends"] = ends
    return tot


lost_total = [0]


def _row(hold: int, what: str, h: dict) -> str:
    lost = h["sent"] - h["accounted"]
    lost_total[0] += lost
    share = 100.0 * h["own_step"] / max(1, h["sent"])
    lp, wp = h["lateness"], h["wall"]
    return (f"| {hold} | {what} | {h['sent']} | {h['own_step']} ({share:.1f} %) | {h['unanswered']} | {lost} | "
            f"{h['timeouts']} | {lp[0]:.0f} / {lp[1]:.0f} / {lp[2]:.0f} | {wp[0]:.2f} ({wp[1]:.2f}) | {h['ends']} | "
            f"{_load()} |")


def _recorded_hello(env: RigEnv) -> bytes:
    """The host's HELLO as a sniffer on the wire would have it."""
    ep = env.client.endpoint
    sent: list[bytes] = []
    real = ep.send

    def send(data, addr=None):
        sent.append(bytes(data))
        return real(data, addr)

    ep.send = send
    try:
        env.client.hello()
    finally:
        ep.send = real
    return [d for d in sent if d[6] == 1][-1]


def _since_start(text: str) -> dict[str, int]:
    m = re.search(r"datagrams since start: (.*)", text)
    return {k: int(v) for k, v in re.findall(r"(\w+) (\d+)", m.group(1))} if m else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=20, help="host-mode episodes per row (default 20)")
    ap.add_argument("--onboard-ticks", type=int, default=1_000_000, help="onboard ticks (default 1e6)")
    ap.add_argument("--max-gap-ms", type=float, default=1.0,
                    help="the target's --max-gap (default 1 ms, the target's own default)")
    ap.add_argument("--loop-fifo", type=int, default=0, metavar="PRIO",
                    help="the target's --loop-fifo (SCHED_FIFO for its loop; root; default 0: none)")
    ap.add_argument("--quick", action="store_true", help="3 episodes a row, 2e5 onboard ticks")
    args = ap.parse_args()
    episodes = 3 if args.quick else args.episodes
    ticks = 200_000 if args.quick else args.onboard_ticks
    cpus = sorted(os.sched_getaffinity(0))
    print(f"# bench_rig: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {len(cpus)} CPUs, "
          f"load average at start {_load()}; the target's --max-gap {args.max_gap_ms:g} ms, --loop-fifo "
          f"{args.loop_fifo}\n")
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = Path(tmp)
        extra = ("--loop-fifo", str(args.loop_fifo)) if args.loop_fifo else ()
        rt, addr = start_target("--scene", "rig", "--log-dir", str(log_dir), "--max-gap", str(args.max_gap_ms),
                                *extra)
        if len(cpus) >= 2:  # the target's loop spins on the last CPU: the host keeps off it
            os.sched_setaffinity(0, set(cpus[:-1]))
        hog = flood = None
        try:
            print("## 1. Onboard, real time, pd-penetration, episodes of 1e5 ticks\n")
            print("| ticks | lateness p50 us | p99 us | p99.9 us | max us | overruns per 1e5 ticks | "
                  "longest skipped run (ticks) | runs of 1 ms or more | tick work p50 us | p99 us | ends | load |")
            print("|---|---|---|---|---|---|---|---|---|---|---|---|")
            r = onboard(addr, log_dir, ticks, 100_000)
            print(f"| {r['ticks']} | {r['p'][0]:.1f} | {r['p'][1]:.1f} | {r['p'][2]:.1f} | {r['max']:.0f} | "
                  f"{r['overruns_per_1e5']:.0f} | {r['longest_skip']} | {r['long_gaps']} | {r['work'][0]:.2f} | "
                  f"{r['work'][1]:.2f} | {r['ends']} | {_load()} |", flush=True)
            head = ("| hold | extra load | commands sent | acted in their own step | observations not answered | "
                    "lost | RigTimeouts | lateness p50/p99/p99.9 us | wall s per 0.4 s episode p50 (max) | ends "
                    "| load |\n|---|---|---|---|---|---|---|---|---|---|---|")
            print(f"\n## 2. Host mode, real time: ImpactCatchRig-v0, pd-penetration residual, {episodes} "
                  "episodes a row\n")
            print(head)
            for extra_load in (False, True):
                if extra_load:
                    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    os.sched_setaffinity(hog.pid, {cpus[0]})
                for hold in (4, 1):
                    env = RigEnv(addr, hold_ticks=hold, residual="pd-penetration", terminate_on_catch=False,
                                 timeout_s=0.1, retries=20)
                    try:
                        h = host_realtime(env, log_dir, hold, episodes)
                    finally:
                        env.close()
                    what = f"a CPU-bound process on CPU {cpus[0]}" if extra_load else "none"
                    print(_row(hold, what, h), flush=True)
            hog.kill()
            hog.wait()
            hog = None
            print(f"\n## 3. The flood: hold 4, {episodes} episodes while a second process sends junk as fast as "
                  "it can\n")
            env = RigEnv(addr, hold_ticks=4, residual="pd-penetration", terminate_on_catch=False, timeout_s=0.1,
                         retries=20)
            try:
                hello = _recorded_hello(env)
                host, port = re.match(r"udp://([^:]+):(\d+)", addr).groups()
                go = log_dir / "go"
                flood = subprocess.Popen([sys.executable, "-c", FLOOD, host, port, hello.hex(), str(go),
                                          str(10**9), str(1.0 * episodes)], stdout=subprocess.PIPE, text=True)
                os.sched_setaffinity(flood.pid, {cpus[0]})
                os.setpriority(os.PRIO_PROCESS, flood.pid, 19)
                assert flood.stdout.readline().strip() == "ready"
                go.touch()
                time.sleep(0.2)
                h = host_realtime(env, log_dir, 4, episodes, seed0=2000)
                out, _ = flood.communicate(timeout=60)
                flood = None
                report = json.loads(out)
            finally:
                env.close()
            print(head)
            print(_row(4, "the flood", h), flush=True)
            n_sent = sum(report["sent"].values())
            print(f"\nflood: {n_sent} datagrams sent in {report['elapsed_s']:.1f} s ({report['sent']}; "
                  f"{report['not_sent']} refused by its own socket), {report['replies']} replies to it "
                  f"({report['reply_bytes']} B)")
        finally:
            for p in (hog, flood):
                if p is not None:
                    p.kill()
                    p.wait()
            stop(rt)
        text = rt.stdout.read()
        print("\n" + "\n".join(line for line in text.splitlines() if "since start" in line))
        counts = _since_start(text)
        if counts:
            print(f"\ncommands in no episode's counters (the rows' 'lost'): {lost_total[0]}; the target's "
                  f"commands_after_end (commands that came after their episode had ended, counted there): "
                  f"{counts.get('commands_after_end', 0)}")
            read = counts.get("datagrams_received", 0)
            print(f"\nthe target's accounts since start: {read} datagrams read = "
                  f"{counts.get('datagrams_accepted', 0)} accepted + "
                  f"{sum(v for k, v in counts.items() if k.startswith('dropped_') and k != 'dropped_kernel')} "
                  f"dropped by reason; {counts.get('dropped_kernel', 0)} dropped by the kernel (its socket's "
                  f"buffer full)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
