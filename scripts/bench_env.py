"""Speed of the Gymnasium layer, as ratios against Gymnasium's own envs measured in the same run.

1. One ``step`` of ``gymnasium.make("ImpactCatch-v0", scene=...)`` (``ideal``, ``rig``) against
   ``MountainCarContinuous-v0``, ``Pendulum-v1`` and ``CartPole-v1`` (all through gymnasium.make,
   so with the same checker/order wrappers).  Goal: rig / MountainCarContinuous <= 1.0.
2. The native vector env on ``rig`` at N = 1, 64, 1024, 4096: env-steps per second against
   Gymnasium's ``CartPoleVectorEnv`` at the same N.  Goal: ratio >= 1.0 at N = 1024.
3. The env's share of a PPO training run's wall time (SB3 adapter, 16 envs).  Goal: < 5 %.

Times are the minimum over repeats after a warm-up (numba compiled and cached first).

    python scripts/bench_env.py [--quick]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import impact_env


def per_step_us(env, actions, repeats: int) -> float:
    env.reset(seed=0)
    best = np.inf
    for _ in range(repeats):
        env.reset(seed=0)
        t0 = time.perf_counter()
        for a in actions:
            _, _, te, tr, _ = env.step(a)
            if te or tr:  # rare here (CartPole); the reset is counted, as in training
                env.reset()
        best = min(best, (time.perf_counter() - t0) / len(actions))
    return best * 1e6


def single_env_table(n_steps: int, repeats: int) -> None:
    rng = np.random.default_rng(0)
    rows = []
    for name, kw in (("MountainCarContinuous-v0", {}), ("Pendulum-v1", {}), ("CartPole-v1", {}),
                     ("ImpactCatch-v0 ideal (1 MHz control)", {"scene": "ideal"}),
                     ("ImpactCatch-v0 rig", {"scene": "rig"})):
        env_id = name.split()[0]
        env = gym.make(env_id, **kw)
        if env_id == "CartPole-v1":  # alternating pushes keep the pole up longest
            acts = [k % 2 for k in range(n_steps)]
        else:
            acts = [np.array([a], dtype=np.float32) for a in rng.uniform(-0.2, 0.2, n_steps)]
        rows.append((name, per_step_us(env, acts, repeats)))
    ref = rows[0][1]
    print("\n## One step of gymnasium.make(...) (min over repeats)\n")
    print("| env | us/step | ratio to MountainCarContinuous |")
    print("|---|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} | {us / ref:.2f} |")


def vector_table(sizes, n_steps: int, repeats: int) -> None:
    from impact_env.env.vector import ImpactCatchVectorEnv

    print("\n## Vector env on rig vs Gymnasium's CartPoleVectorEnv (env-steps/s)\n")
    print("| N | ImpactCatch rig | CartPoleVectorEnv | ratio |")
    print("|---|---|---|---|")
    for n in sizes:
        ours = ImpactCatchVectorEnv(n, "rig")
        cart = gym.make_vec("CartPole-v1", num_envs=n, vectorization_mode="vector_entry_point")
        rates = []
        for env, acts in ((ours, np.zeros((n, 1), np.float32)), (cart, np.zeros(n, np.int64))):
            env.reset(seed=0)
            env.step(acts)
            best = np.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                for _ in range(n_steps):
                    env.step(acts)
                best = min(best, time.perf_counter() - t0)
            rates.append(n * n_steps / best)
        print(f"| {n} | {rates[0]:.3g} | {rates[1]:.3g} | {rates[0] / rates[1]:.2f} |")


def ppo_share(total_steps: int) -> None:
    from stable_baselines3 import PPO

    from impact_env.env.sb3_vecenv import make_sb3_vec_env

    env = make_sb3_vec_env("rig", num_envs=16)
    spent = [0.0]
    step_wait = env.step_wait

    def timed_step_wait():
        t0 = time.perf_counter()
        out = step_wait()
        spent[0] += time.perf_counter() - t0
        return out

    env.step_wait = timed_step_wait
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=256, seed=0, device="cpu", verbose=0)
    model.learn(4096)  # warm-up (torch and numba)
    spent[0] = 0.0
    t0 = time.perf_counter()
    model.learn(total_steps, reset_num_timesteps=False)
    wall = time.perf_counter() - t0
    print(f"\n## Env share of a PPO run (16 rig envs, {total_steps} steps, default MlpPolicy)\n")
    print(f"PPO wall {wall:.2f} s, env step_wait {spent[0]:.2f} s: env share {100 * spent[0] / wall:.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and repeats (a smoke run)")
    args = ap.parse_args()
    impact_env.load_scene("rig")
    n_steps, repeats = (500, 2) if args.quick else (3000, 5)
    single_env_table(n_steps, repeats)
    vector_table((1, 64, 1024) if args.quick else (1, 64, 1024, 4096), 20 if args.quick else 100,
                 2 if args.quick else 3)
    ppo_share(8192 if args.quick else 32768)


if __name__ == "__main__":
    main()
