"""Where a training run's time goes on this machine (issue 26, "a good agent in minutes"): the
native vector env alone at several batch sizes, the policy network's forward pass for a batch of
observations, and one PPO / SAC gradient step at several minibatch sizes, with 1 and 2 torch
threads.  Absolute figures depend on what else shares the cores: read them with the load average
printed first.

    python scripts/bench_agents.py [--envs 16,64,256,1024] [--batches 256,1024,4096,16384] [--threads 1,2]

Its output, with the load it ran at, is kept in docs/results/agents/bench_agents.txt (docs/env.md,
"Where a training run's time goes", names the script): at load 2-3 the env alone stepped 68, 175, 98
and 54 thousand policy steps/s at 16, 64, 256 and 1024 envs (hold 4, the compiled residual law); a
PPO gradient step of a 64x64 actor and critic cost 5.7 us per sample at batch 4096 with one thread, so the
update, not the env, bounds PPO's throughput; 2 threads gave erratic, mostly slower figures on
the 2 shared cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

ENV_KW = dict(observation="sensors", history=1, hold_ticks=4, residual="pd-penetration", effort_weight=0.1,
              terminate_on_catch=False)


def env_rate(n: int, scene: str = "rig-randomized") -> tuple[float, float]:
    """(policy steps/s, ms per vector step) of ``n`` envs stepping action 0."""
    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    env = make_sb3_vec_env(scene, num_envs=n, monitor=False, **ENV_KW)
    env.seed(0)
    env.reset()
    a = np.zeros((n, 1), np.float32)
    env.step(a)  # compilation, first blocks
    steps = max(20, 40_000 // n)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(a)
    dt = time.perf_counter() - t0
    env.close()
    return steps * n / dt, dt / steps * 1e3


def torch_costs(threads: int, envs: list[int], batches: list[int]) -> list[str]:
    import torch
    from stable_baselines3 import PPO, SAC

    from impact_env.env.sb3_vecenv import ActionLimit, make_sb3_vec_env

    torch.set_num_threads(threads)
    env = make_sb3_vec_env("rig-randomized", num_envs=16, monitor=False, **ENV_KW)
    arch = dict(net_arch=dict(pi=[64, 64], vf=[64, 64]))
    ppo = PPO("MlpPolicy", env, policy_kwargs=arch, device="cpu", seed=0)
    pol, size = ppo.policy, env.observation_space.shape[0]
    out = []
    for n in envs:
        obs = torch.randn(n, size)
        with torch.no_grad():
            for _ in range(5):
                pol(obs)
            t0 = time.perf_counter()
            for _ in range(200):
                pol(obs)
        out.append(f"  threads {threads}: PPO policy forward, {n} observations: "
                   f"{(time.perf_counter() - t0) / 200 * 1e3:.3f} ms")
    for b in batches:
        obs, act = torch.randn(b, size), torch.randn(b, 1)
        for k in range(33):
            if k == 3:
                t0 = time.perf_counter()
            v, lp, _ = pol.evaluate_actions(obs, act)
            loss = -lp.mean() + (v ** 2).mean()
            pol.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(pol.parameters(), 0.5)
            pol.optimizer.step()
        dt = (time.perf_counter() - t0) / 30
        out.append(f"  threads {threads}: PPO gradient step, batch {b}: {dt * 1e3:.2f} ms, "
                   f"{dt / b * 1e6:.2f} us/sample")
    senv = ActionLimit(make_sb3_vec_env("rig-randomized", num_envs=64, monitor=False, **ENV_KW), 0.25)
    for b in batches[:3]:
        sac = SAC("MlpPolicy", senv, policy_kwargs=dict(net_arch=[64, 64]), device="cpu", batch_size=b,
                  learning_starts=0, n_steps=16, gamma=0.998, seed=0)
        sac.learn(64 * 40)  # something in the buffer
        t0 = time.perf_counter()
        sac.train(gradient_steps=20, batch_size=b)
        dt = (time.perf_counter() - t0) / 20
        out.append(f"  threads {threads}: SAC gradient step, batch {b}: {dt * 1e3:.2f} ms, "
                   f"{dt / b * 1e6:.2f} us/sample")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", default="16,64,256,1024")
    p.add_argument("--batches", default="256,1024,4096,16384")
    p.add_argument("--threads", default="1,2")
    a = p.parse_args(argv)
    envs = [int(x) for x in a.envs.split(",")]
    batches = [int(x) for x in a.batches.split(",")]
    print(f"load average at start: {os.getloadavg()[0]:.2f}", flush=True)
    for n in envs:
        rate, ms = env_rate(n)
        print(f"env alone, {n} envs: {rate:.0f} policy steps/s ({ms:.2f} ms per vector step)", flush=True)
    for t in (int(x) for x in a.threads.split(",")):
        for line in torch_costs(t, envs, batches):
            print(line, flush=True)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
