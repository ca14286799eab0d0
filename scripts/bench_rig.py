"""How the target's compiled real-time core keeps time on this machine (issue 25's figures).

    python scripts/bench_rig.py [--episodes 20] [--onboard-ticks 1000000] [--quick]

Targets run as separate processes (``impact-env rig serve --virtual --log-dir TMP``) on loopback,
as on a rig with its host on the same network; the figures come from the episodes' logs, read
from the target's log folder.

1. Onboard, real time: the compiled pd-penetration law in episodes of 10 s (10^5 ticks) until
   ``--onboard-ticks`` ticks (default 10^6): tick lateness (start minus deadline) p50 / p99 /
   p99.9 / max, overruns (rows flagged OVERRUN) per 10^5 ticks, the longest run of skipped ticks,
   episodes that ended OVERRUN (a gap over 1 ms), and the tick's work (read, front end, policy,
   safety, the virtual rig's hardware stage, log row) p50 / p99.
2. Host mode, real time: ``ImpactCatchRig-v0`` (pd-penetration residual, actions drawn at
   random), ``--episodes`` episodes each at hold 4 and hold 1, first alone, then with a CPU-bound
   process of the bench's own pinned to core 0: the share of the host's commands that acted
   within their own step (a row of the step driven by the step's command), commands lost (sent
   and counted nowhere: not accepted, not late, not after the end), RigTimeouts, tick lateness
   p50 / p99 / p99.9 and the wall time of an episode (reset to its end).

Wall-clock figures of a shared machine without a real-time kernel: they say what this machine
does under the load it had (the 1-minute load average is printed with them), not what a rig
controller with an isolated core would.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from rig_helpers import start_target, stop  # noqa: E402

from impact_env.policy.export import export_policy  # noqa: E402
from impact_env.rig.host import RigClient  # noqa: E402
from impact_env.rig.log import list_episodes, read_episode  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def onboard(addr: str, log_dir: Path, ticks: int, horizon: int) -> dict:
    """pd-penetration onboard in episodes of ``horizon`` ticks until ``ticks`` have passed."""
    scene = load_scene("rig")
    c = RigClient(addr)
    late, work, overruns, longest, ends, passed = [], [], 0, 0, {}, 0
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
            ends[log.meta.end_reason] = ends.get(log.meta.end_reason, 0) + 1
            passed += int(log["tick"][-1])
            seed += 1
    finally:
        c.close()
    lat, w = np.concatenate(late) / 1e3, np.concatenate(work)
    p = np.percentile(lat, [50, 99, 99.9])
    return {"ticks": passed, "rows": lat.size, "p": p, "max": float(lat.max()),
            "overruns_per_1e5": 1e5 * overruns / passed, "longest_skip": longest,
            "work": np.percentile(w, [50, 99]), "ends": ends, "episodes": seed - 1}


def _file(log_dir: Path, episode: int, timeout_s: float = 30.0) -> Path:
    deadline = time.monotonic() + timeout_s
    while True:
        for p in list_episodes(log_dir):
            if p.name.endswith(f"_{episode:06d}.h5"):
                return p
        if time.monotonic() > deadline:
            raise TimeoutError(f"no log of episode {episode} in {log_dir}")
        time.sleep(0.02)


def host_realtime(addr: str, log_dir: Path, hold: int, episodes: int) -> dict:
    from impact_env.rig.host import RigEnv
    from impact_env.rig.transport import RigTimeout

    env = RigEnv(addr, hold_ticks=hold, residual="pd-penetration", terminate_on_catch=False, timeout_s=0.1,
                 retries=20)
    rng = np.random.default_rng(0)
    tot = {"sent": 0, "accounted": 0, "own_step": 0, "timeouts": 0}
    late_ns, wall, ends = [], [], {}
    try:
        for k in range(episodes):
            sent = 0
            t0 = time.perf_counter()
            try:
                env.reset(seed=1000 + k)
                for _ in range(env.max_steps):
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
            tick = log["tick"].astype(np.int64)[:-1]
            cstep = log["command_step"].astype(np.int64)[:-1]
            tot["own_step"] += np.unique(cstep[(cstep >= 0) & (tick // hold == cstep)]).size
            late_ns.append(log["lateness_ns"][1:-1])
    finally:
        env.close()
    lat = np.concatenate(late_ns) / 1e3 if late_ns else np.zeros(1)
    tot["lateness"] = np.percentile(lat, [50, 99, 99.9])
    tot["wall"] = np.percentile(wall, [50, 100]) if wall else np.zeros(2)
    tot["ends"] = ends
    return tot


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=20, help="host-mode episodes per row (default 20)")
    ap.add_argument("--onboard-ticks", type=int, default=1_000_000, help="onboard ticks (default 1e6)")
    ap.add_argument("--max-gap-ms", type=float, default=1.0,
                    help="the target's --max-gap (default 1 ms, the target's own default)")
    ap.add_argument("--quick", action="store_true", help="3 episodes a row, 2e5 onboard ticks")
    args = ap.parse_args()
    episodes = 3 if args.quick else args.episodes
    ticks = 200_000 if args.quick else args.onboard_ticks
    print(f"# bench_rig: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} CPUs, "
          f"load average at start {_load()}; the target's --max-gap {args.max_gap_ms:g} ms\n")
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = Path(tmp)
        rt, addr = start_target("--scene", "rig", "--log-dir", str(log_dir),
                                "--max-gap", str(args.max_gap_ms))
        hog = None
        try:
            print("## 1. Onboard, real time, pd-penetration, episodes of 1e5 ticks\n")
            print("| ticks | lateness p50 us | p99 us | p99.9 us | max us | overruns per 1e5 ticks | "
                  "longest skipped run (ticks) | tick work p50 us | p99 us | ends | load |")
            print("|---|---|---|---|---|---|---|---|---|---|---|")
            r = onboard(addr, log_dir, ticks, 100_000)
            print(f"| {r['ticks']} | {r['p'][0]:.1f} | {r['p'][1]:.1f} | {r['p'][2]:.1f} | {r['max']:.0f} | "
                  f"{r['overruns_per_1e5']:.0f} | {r['longest_skip']} | {r['work'][0]:.2f} | "
                  f"{r['work'][1]:.2f} | {r['ends']} | {_load()} |", flush=True)
            print(f"\n## 2. Host mode, real time: ImpactCatchRig-v0, pd-penetration residual, {episodes} "
                  "episodes a row\n")
            print("| hold | extra load | commands sent | acted in their own step | lost | RigTimeouts | "
                  "lateness p50/p99/p99.9 us | wall s per 0.4 s episode p50 (max) | ends | load |")
            print("|---|---|---|---|---|---|---|---|---|---|")
            for extra in (False, True):
                if extra:
                    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
                    os.sched_setaffinity(hog.pid, {0})
                for hold in (4, 1):
                    h = host_realtime(addr, log_dir, hold, episodes)
                    lost = h["sent"] - h["accounted"]
                    share = 100.0 * h["own_step"] / max(1, h["sent"])
                    lp, wp = h["lateness"], h["wall"]
                    what = "a CPU-bound process on core 0" if extra else "none"
                    print(f"| {hold} | {what} | {h['sent']} | {h['own_step']} ({share:.1f} %) | {lost} | "
                          f"{h['timeouts']} | {lp[0]:.0f} / {lp[1]:.0f} / {lp[2]:.0f} | "
                          f"{wp[0]:.2f} ({wp[1]:.2f}) | "
                          f"{h['ends']} | "
                          f"{_load()} |", flush=True)
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
            stop(rt)
        print("\n" + "\n".join(line for line in rt.stdout.read().splitlines() if "since start" in line))
    return 0


if __name__ == "__main__":
    sys.exit(main())
