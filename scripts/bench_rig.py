"""How the target keeps time on this machine: tick lateness, overruns, the host's round trip, and
what a tick's work costs.

    python scripts/bench_rig.py [--quick] [--ticks N]

Targets run as separate processes (``impact-env rig serve --virtual``) on loopback, as on a rig
with its host on the same network.

1. Real time, onboard: episodes of the rig's 0.4 s horizon, back to back, until N ticks have
   run (default 10^5: 25 episodes), with the compiled pd-penetration law and with the committed
   PPO agent (its compiled policy file); from the episodes' logs: tick lateness (start minus
   deadline) p50 / p99 / p99.9 / max, overruns (ticks that started more than a period late) per
   10^5 ticks, and the tick's work (read, front end, policy, safety, apply to the virtual rig,
   log) p50 / p99.
2. Host mode round trip: the host's time from sending COMMAND n to receiving OBSERVATION n + 1,
   p50 / p99, in lock-step (pure round trip plus one tick of work) and in real time with
   hold_ticks = 10 (1 ms policy period: the host must answer within it).
3. Host mode in real time, ``ImpactCatchRig-v0`` with hold_ticks = 4 and the pd-penetration
   residual (the docs' example), episodes to their end: what became of the host's commands
   (sent, acted, counted late, superseded, expired; lost = sent and counted nowhere, goal 0),
   the steps whose command acted after the step's first tick (and by how many ticks: p50 /
   p99 / p99.9), skipped ticks and whether every one is flagged on the next row, and tick
   lateness p50 / p99 / p99.9.
4. The onboard ``act`` alone is measured by ``scripts/bench_policy.py``.

Wall-clock figures of a shared machine without a real-time kernel: they say what this machine
does, not what a rig controller with an isolated core would (see README).
"""

from __future__ import annotations

import argparse
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
from impact_env.rig.clock import lateness_summary  # noqa: E402
from impact_env.rig.host import RigClient  # noqa: E402
from impact_env.scene import load_scene  # noqa: E402

MODEL = "ppo:agents/models/best/model.zip"  # the shipped agent: residual on pd-penetration, hold 4


def onboard(addr: str, spec: str, ticks: int) -> dict:
    """Episodes of the scene's horizon (seeds 1, 2, ...) until ``ticks`` ticks have run."""
    scene = load_scene("rig")
    horizon = int(round(scene.episode.horizon * scene.control_rate))
    c = RigClient(addr)
    late, work, overruns, ends = [], [], 0, set()
    try:
        pol = export_policy(spec, scene)
        seed = 1
        while sum(len(x) for x in late) < ticks:
            c.arm("onboard", seed, horizon, policy=pol)
            end = c.wait_end(timeout_s=60.0 + 3.0 * horizon / scene.control_rate)
            log = c.fetch_log(end.episode, end.data_sha256)
            n = log.n_ticks - 1  # the last row is the final observation only
            late.append(log["lateness_ns"][1:n])
            work.append(log["compute_ns"][:n] / 1e3)
            overruns += int(log.meta.counters.get("overruns", 0))
            ends.add(log.meta.end_reason)
            seed += 1
    finally:
        c.close()
    late_all, work_all = np.concatenate(late), np.concatenate(work)
    out = lateness_summary(late_all, ticks=late_all.size, overruns=overruns)
    out["work_p50_us"], out["work_p99_us"] = (float(x) for x in np.percentile(work_all, [50, 99]))
    out["end"] = "/".join(sorted(ends))
    out["episodes"] = len(late)
    return out


def round_trip(addr: str, steps: int, hold: int) -> dict:
    c = RigClient(addr)
    rtt = []
    try:
        c.arm("host", 2, steps * hold, hold_ticks=hold, link_timeout_ms=2000)
        obs = c.observation(0, 5.0)
        for n in range(steps):
            t0 = time.perf_counter()
            c.command(n, 0.05)
            obs = c.observation(n + 1, 1.0)
            if obs is None:
                break
            rtt.append(time.perf_counter() - t0)
    finally:
        c.close()
    x = np.asarray(rtt) * 1e6
    return {"p50_us": float(np.percentile(x, 50)), "p99_us": float(np.percentile(x, 99)), "steps": len(x)}


def host_realtime(addr: str, hold: int, episodes: int) -> dict:
    """``episodes`` episodes of ImpactCatchRig-v0 in real time (module doc, 3)."""
    from impact_env.rig.host import RigEnv
    from impact_env.rig.safety import OVERRUN
    from impact_env.rig.transport import RigTimeout

    env = RigEnv(addr, hold_ticks=hold, residual="pd-penetration", terminate_on_catch=False, timeout_s=0.1,
                 retries=20)
    rng = np.random.default_rng(0)
    tot = {"sent": 0, "accounted": 0, "acted": 0, "late": 0, "superseded": 0, "expired": 0, "unused": 0,
           "steps": 0, "acted_late": 0, "ticks": 0, "skipped": 0, "skipped_flagged": 0, "overrun_rows": 0,
           "rig_timeouts": 0}
    delay, late_ns, ends = [], [], {}
    try:
        for k in range(episodes):
            sent = 0
            try:  # a RigTimeout is counted (the figure the table prints), and the next episode runs
                env.reset(seed=1000 + k)
                for _ in range(env.max_steps):
                    sent += 1
                    _o, _r, te, tr, info = env.step(np.array([rng.uniform(-0.3, 0.3)], np.float32))
                    if te or tr:
                        break
            except RigTimeout:
                tot["rig_timeouts"] += 1
                ends["RigTimeout"] = ends.get("RigTimeout", 0) + 1
                continue
            why = info.get("end_reason", "?")
            ends[why] = ends.get(why, 0) + 1
            log = env.client.fetch_log(env.client.episode)
            c = log.meta.counters
            tot["sent"] += sent
            tot["steps"] += sent
            tot["accounted"] += c["commands_accepted"] + c["commands_late"]
            tot["acted"] += c["commands_acted"]
            tot["late"] += c["commands_late"]
            tot["superseded"] += c["commands_superseded"]
            tot["expired"] += c["commands_expired"]
            tot["unused"] += c["commands_unused_at_end"]
            tick = log["tick"].astype(np.int64)
            step = log["command_step"].astype(np.int64)
            skipped = log["skipped_ticks"].astype(np.int64)
            status = log["status"].astype(np.int64)
            tot["ticks"] += int(tick[-1]) + 1
            tot["skipped"] += int(c["skipped_ticks"])
            gaps = np.diff(tick) - 1
            tot["skipped_flagged"] += int(np.sum(gaps[(gaps == skipped[1:]) & ((status[1:] & OVERRUN) != 0)]))
            tot["overrun_rows"] += int(c["overruns"])
            # each acted command: its first tick after its step's first tick, in ticks
            acted = step >= 0
            _u, first = np.unique(step[acted], return_index=True)
            d = tick[acted][first] - step[acted][first] * hold
            delay.append(d)
            tot["acted_late"] += int(np.count_nonzero(d > 0))
            late_ns.append(log["lateness_ns"][1:-1])
    finally:
        env.close()
    d = np.concatenate(delay) if delay else np.zeros(1)
    lat = np.concatenate(late_ns) / 1e3
    tot["delay_p"] = [float(x) for x in np.percentile(d, [50, 99, 99.9])] if d.size else [0.0] * 3
    tot["lateness_p"] = [float(x) for x in np.percentile(lat, [50, 99, 99.9])]
    tot["ends"] = ends
    tot["episodes"] = episodes
    return tot


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10^4 ticks and fewer round trips")
    ap.add_argument("--ticks", type=int, default=None, help="ticks of each real-time episode (default 1e5)")
    args = ap.parse_args()
    ticks = args.ticks or (10_000 if args.quick else 100_000)
    steps = 500 if args.quick else 3000
    with tempfile.TemporaryDirectory():
        rt, rt_addr = start_target("--scene", "rig")
        try:
            print(f"## 1. Real time, onboard, {ticks} ticks at 10 kHz (from the episode logs)\n")
            print("| policy | lateness p50 us | p99 us | p99.9 us | max us | overruns per 1e5 ticks | "
                  "tick work p50 us | p99 us | end |")
            print("|---|---|---|---|---|---|---|---|---|")
            for spec in ("pd-penetration", MODEL):
                r = onboard(rt_addr, spec, ticks)
                print(f"| {spec} | {r['p50_us']:.1f} | {r['p99_us']:.1f} | {r['p999_us']:.1f} | "
                      f"{r['max_us']:.0f} | {r['overruns_per_1e5']:.0f} | {r['work_p50_us']:.1f} | "
                      f"{r['work_p99_us']:.1f} | {r['end']} |")
            rt_host = round_trip(rt_addr, steps, 10)
            hr = host_realtime(rt_addr, 4, 3 if args.quick else 20)
        finally:
            stop(rt)
        after_end = _after_end(rt.stdout.read())
        ls, ls_addr = start_target("--scene", "rig", "--lockstep")
        try:
            ls_host = round_trip(ls_addr, steps, 1)
        finally:
            stop(ls)
    print("\n## 2. Host mode: COMMAND n -> OBSERVATION n + 1 at the host\n")
    print("| target | p50 us | p99 us | steps |")
    print("|---|---|---|---|")
    print(f"| lock-step, hold 1 | {ls_host['p50_us']:.0f} | {ls_host['p99_us']:.0f} | {ls_host['steps']} |")
    print(f"| real time, hold 10 (1 ms policy period) | {rt_host['p50_us']:.0f} | {rt_host['p99_us']:.0f} | "
          f"{rt_host['steps']} |")
    lost = hr["sent"] - hr["accounted"] - after_end
    print(f"\n## 3. Host mode, real time: ImpactCatchRig-v0, hold 4, pd-penetration residual, "
          f"{hr['episodes']} episodes ({hr['ticks']} ticks; ends {hr['ends']})\n")
    print("| commands sent | acted | counted late | superseded | expired | after the end | lost | "
          "steps acted late (of acted) | delay p50/p99/p99.9 ticks | skipped ticks | flagged | "
          "overrun rows | tick lateness p50/p99/p99.9 us | RigTimeouts |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    dp, lp = hr["delay_p"], hr["lateness_p"]
    print(f"| {hr['sent']} | {hr['acted']} | {hr['late']} | {hr['superseded']} | {hr['expired']} | "
          f"{after_end} | "
          f"{lost} | {hr['acted_late']} ({hr['acted']}) | {dp[0]:.0f} / {dp[1]:.0f} / {dp[2]:.0f} | "
          f"{hr['skipped']} | {hr['skipped_flagged']} | {hr['overrun_rows']} | "
          f"{lp[0]:.0f} / {lp[1]:.0f} / {lp[2]:.0f} | {hr['rig_timeouts']} |")
    return 0


def _after_end(text: str) -> int:
    """Commands the target received for episodes already over (its stop line)."""
    import re

    m = re.search(r"commands_after_end (\d+)", text)
    return int(m.group(1)) if m else 0


if __name__ == "__main__":
    sys.exit(main())
