"""Speed of the Gymnasium layer, as ratios against Gymnasium's own envs measured in the same run.

1. One ``step`` of ``gymnasium.make("ImpactCatch-v0", scene=...)`` (``ideal``, ``rig``) against
   ``MountainCarContinuous-v0``, ``Pendulum-v1`` and ``CartPole-v1`` (all through gymnasium.make,
   so with the same checker/order wrappers).  Goal: rig / MountainCarContinuous <= 1.0.
2. The native vector env on ``rig`` at N = 1, 64, 1024, 4096: env-steps per second against
   Gymnasium's ``CartPoleVectorEnv`` at the same N.  Goal: ratio >= 1.0 at N = 1024.
3. The env's share of a PPO training run's wall time (SB3 adapter, 16 envs).  Goal: < 5 %.
4. The batched control period as ``compare`` runs it (``rollout`` of ``rig`` at N = 400 episodes,
   ``passive`` and ``pd-penetration``, one thread), per env per period, with the default
   integrator and with the former default (RK4 at 1 us) in the same run.  Goal: <= 0.3 us.
   Then what it is made of: the scene's effects switched on one at a time, then the policy
   (``--only period-parts`` alone).
5. Threads (``threads=`` of the Simulator, the vector env, rollout and compare): first the
   issue's table, ``ImpactCatchVectorEnv(N, "rig", hold_ticks=h, threads=k)`` at N = 1024,
   4096, 16384, hold 1 and 4, with 1, 2 and every CPU's thread and the former Python threads
   beside (the first steps after a reset, the same work in every round), a scaling model and a
   parallel call's fixed cost (``--only vector-threads`` alone); then the speed-up of
   2 threads over 1, measured in alternating rounds on the same objects: the simulator's step on
   ``rig`` at N = 16 .. 1024 (where a block of envs starts to pay: the threshold
   ``MIN_BLOCK_ENVS``), the vector env at N = 1024, and a rollout as ``compare`` runs it (``rig``,
   ``passive`` and ``pd-penetration`` through the Python loop, the compiled ``pd-penetration``
   through the compiled loop) at N = 256 and 1024.  The load average is printed beside it: on a
   shared machine other jobs take the second core.

6. One step of the single env part by part, and a vector env's reset per env (``--only step``).

``--only ratios`` runs 1 and 2 alone (the step and vector ratios).

Times are the minimum over repeats after a warm-up (numba compiled and cached first).

    python scripts/bench_env.py [--quick] [--only ratios|threads|vector-threads|period|period-parts|step]
"""

from __future__ import annotations

import argparse
import functools
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


def _loadavg() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "n/a"


def _ratio(run, rounds: int) -> tuple[float, float, float, float]:
    """Alternating rounds of ``run(threads)`` for threads 1 and 2; returns (min s with 1, min s
    with 2, ratio of the two minima, cores busy with 2: the process's CPU time over the wall time
    of that round, which says whether the second thread found a free core)."""
    best = {1: np.inf, 2: np.inf}
    busy = 0.0
    for _ in range(rounds):
        for th in (1, 2):
            t0, c0 = time.perf_counter(), time.process_time()
            run(th)
            wall = time.perf_counter() - t0
            if wall < best[th]:
                best[th] = wall
                if th == 2:
                    busy = (time.process_time() - c0) / wall
    return best[1], best[2], best[1] / best[2], busy


def _rounds(runs: dict, rounds: int) -> dict:
    """Alternating rounds of every ``runs[key]()``; per key (min wall s, cores busy in that
    round: the process's CPU time over its wall time, which says whether the threads found
    free cores).  A run may time itself: it then returns (wall s, CPU s)."""
    best = {key: (np.inf, 0.0) for key in runs}
    for _ in range(rounds):
        for key, run in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            timed = run()
            wall, cpu = timed if timed is not None else (time.perf_counter() - t0, time.process_time() - c0)
            if wall < best[key][0]:
                best[key] = (wall, cpu / wall)
    return best


def _former(run):
    """``run`` with the blocks in the former pool of Python threads (impact_env._threads's
    fallback), as every threaded step ran before the compiled parallel region."""
    import impact_env._threads as threads_module

    def former():
        keep = threads_module._STATE["no_parallel"]
        threads_module._STATE["no_parallel"] = True
        try:
            return run()
        finally:
            threads_module._STATE["no_parallel"] = keep

    return former


def _episode_start(env, acts, steps: int, threads: int):
    """The first ``steps`` steps after ``env.reset(seed=0)`` with ``threads`` threads: (wall s,
    CPU s) of the steps alone.  Every round and thread count does the same work (the work of a
    step changes along an episode: the impact, the bounces, the rest)."""
    env.task.sim.threads = threads
    env.reset(seed=0)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        env.step(acts)
    return time.perf_counter() - t0, time.process_time() - c0


def vector_threads_table(quick: bool, sizes=(1024, 4096, 16384), holds=(1, 4)) -> None:
    """The issue's table: ``ImpactCatchVectorEnv(N, "rig", hold_ticks=h, threads=k)``, zero
    actions, env-steps per second over the first steps of an episode with 1, 2 and every
    CPU's thread, and with the former Python threads beside (same process, alternating rounds,
    min)."""
    import os

    import numba

    import impact_env._threads as threads_module
    from impact_env.env.vector import ImpactCatchVectorEnv

    cpus = threads_module.machine_threads()
    counts = sorted({1, 2, cpus})
    rounds = 5 if quick else 11
    print(f"\n## Threads: the vector env (rig, zero actions), env-steps/s (speed-up over 1 thread) "
          f"[cores busy]\n\n(CPUs this process may use: {cpus}; OMP_WAIT_POLICY="
          f"{os.environ.get('OMP_WAIT_POLICY', 'unset')}; load average before: {_loadavg()})\n")
    cols = [f"{k} thread{'s' if k > 1 else ''}" for k in counts] + [f"{k} former Python threads"
                                                                  for k in counts if k > 1]
    print("| N | hold | steps after a reset | " + " | ".join(cols) + " |")
    print("|---|---|---|" + "---|" * len(cols))
    models = []
    for hold in holds:
        for n in sizes:
            env = ImpactCatchVectorEnv(n, "rig", hold_ticks=hold)
            acts = np.zeros((n, 1), np.float32)
            env.reset(seed=0)
            env.step(acts)  # (the serial kernels bound, the parallel ones compiled below)
            steps = max(4, int((4e4 if quick else 1e5) / (n * hold)))
            runs = {k: functools.partial(_episode_start, env, acts, steps, k) for k in counts}
            runs.update({("former", k): _former(functools.partial(_episode_start, env, acts, steps, k))
                         for k in counts if k > 1})
            for r in runs.values():  # warm-up: compiles (or loads) the parallel shim
                r()
            res = _rounds(runs, rounds)
            t1 = res[1][0]
            cells = [f"{n * steps / t:.3g} ({t1 / t:.2f}x) [{busy:.2f}]" for t, busy in res.values()]
            print(f"| {n} | {hold} | {steps} | " + " | ".join(cells) + " |")
            if n in (min(sizes), max(sizes)):
                models.append(_scaling_model(env, acts, steps))
    print(f"\n(numba's threading layer: {numba.threading_layer()}; load average after: {_loadavg()})")
    for model in models:
        print(model)


def _scaling_model(env, acts, steps) -> str:
    """Amdahl's model of the vector env's step from one-thread measurements over the same
    steps as the table: the threaded work (the compiled step: the simulator's and the task's
    kernels, the info columns they write included, and the sensor noise's top-up, which runs
    over the blocks in Python threads), the serial rest (Python, the info arrays) and a
    parallel call's fixed cost; the speed-ups it predicts."""
    from impact_env.env import task_kernel

    task = env.task
    sim = task.sim
    sim.threads = 1
    t_env, t_kernel = np.inf, np.inf
    for _ in range(5):
        t_env = min(t_env, _episode_start(env, acts, steps, 1)[0] / steps)
        env.reset(seed=0)
        a = np.zeros(sim.n)
        t0 = time.perf_counter()
        for _ in range(steps):  # the compiled step (writing the info columns, as the env's) and the noise
            task.step(a, None, np.empty((task_kernel.N_COL, sim.n)))
        t_kernel = min(t_kernel, (time.perf_counter() - t0) / steps)
    fixed = _call_overhead()
    serial = max(t_env - t_kernel, 0.0)
    lines = [f"\nScaling model at N = {sim.n}, hold {sim.hold}, the first {steps} steps (one thread): a step "
             f"{1e6 * t_env:.0f} us, of which the compiled step and the noise (threaded) "
             f"{1e6 * t_kernel:.0f} us and the rest {1e6 * serial:.0f} us (serial: Python, the info "
             f"arrays); a parallel call's fixed cost {1e6 * fixed:.1f} us (2 blocks)."]
    preds = [f"{k} threads {t_env / (serial + t_kernel / k + fixed):.1f}x" for k in (2, 4, 8, 16, 32)]
    lines.append("  predicted speed-up (free cores, memory bandwidth not limiting): " + ", ".join(preds))
    return "\n".join(lines)


def _call_overhead() -> float:
    """A parallel call's fixed cost (s): the simulator's kernel on 2 inactive envs in 2 blocks
    (one compiled region) less the same in one block (the serial call)."""
    import impact_env.sim.simulator as simulator_module

    keep = simulator_module.MIN_BLOCK_ENVS
    simulator_module.MIN_BLOCK_ENVS = 1
    try:
        sim = simulator_module.Simulator("rig", 2)
    finally:
        simulator_module.MIN_BLOCK_ENVS = keep
    sim.reset([np.random.default_rng(i) for i in range(2)])
    a, off = np.zeros(2), np.zeros(2, dtype=bool)
    sim.step(a)
    one, two = [(0, 2)], [(0, 1), (1, 2)]
    args = (a, off, sim.params, sim.state)
    sim._run(two, args)
    reps = 2000

    def call(blocks):
        for _ in range(reps):
            sim._run(blocks, args)

    res = _rounds({1: functools.partial(call, one), 2: functools.partial(call, two)}, 5)
    return (res[2][0] - res[1][0]) / reps


def threads_table(quick: bool) -> None:
    import os

    from impact_env.eval.rollout import rollout
    from impact_env.policy.export import export_policy
    from impact_env.policy.registry import make_policy
    from impact_env.sim import simulator as simulator_module

    vector_threads_table(quick)
    rounds = 3 if quick else 7
    print(f"\n## Threads: 2 against 1 (os.cpu_count() = {os.cpu_count()}; load average before: "
          f"{_loadavg()})\n")
    print("Simulator.step on rig, every block split (threshold off), per step:\n")
    print("| N | 1 thread us | 2 threads us | speed-up | cores busy with 2 |")
    print("|---|---|---|---|---|")
    keep = simulator_module.MIN_BLOCK_ENVS
    simulator_module.MIN_BLOCK_ENVS = 1
    try:
        for n in (4, 8, 16, 32, 64, 128, 256, 1024):
            sim = simulator_module.Simulator("rig", n)
            sim.reset([np.random.default_rng(i) for i in range(n)])
            z = np.zeros(n)
            sim.step(z)
            reps = max(10, (2000 if quick else 10000) // n)

            def run(th, sim=sim, z=z, reps=reps):
                sim.threads = th
                for _ in range(reps):
                    sim.step(z)

            t1, t2, r, busy = _ratio(run, rounds)
            print(f"| {n} | {1e6 * t1 / reps:.1f} | {1e6 * t2 / reps:.1f} | {r:.2f} | {busy:.2f} |")
    finally:
        simulator_module.MIN_BLOCK_ENVS = keep
    print(f"\n(threshold in use: MIN_BLOCK_ENVS = {simulator_module.MIN_BLOCK_ENVS} envs per block; a "
          f"parallel call's fixed cost {1e6 * _call_overhead():.1f} us)\n")

    # a rollout's control period as compare runs it: the wall time between the rollout's first
    # progress report (after CHUNK steps) and its last, per step: the reset of a randomised scene
    # (every env draws and validates its scene in Python, about 2 ms per env) is left out
    scene = impact_env.load_scene("rig")
    n_steps = 400 if quick else 1000
    horizon = n_steps * scene.control_period
    print("| workload | 1 thread | 2 threads | speed-up | cores busy with 2 |")
    print("|---|---|---|---|---|")
    for spec in ("passive", "pd-penetration", "compiled pd-penetration"):
        # (the compiled loop at N = 8 too: two blocks of MIN_BLOCK_EPISODES = 4, its threshold)
        for n in (8, 256, 1024) if spec.startswith("compiled") else (256, 1024):
            measured = {}

            def roll(th, spec=spec, n=n, measured=measured):
                name = spec.split()[-1]
                pol = export_policy(name, scene) if spec.startswith("compiled") else make_policy(name, scene)
                marks: list[tuple[float, int]] = []
                done = [0]

                def progress(k):
                    done[0] += k
                    marks.append((time.perf_counter(), done[0]))

                rollout(scene, pol, range(n), horizon=horizon, trace_rate=1e4, threads=th, progress=progress,
                        trace_rows=[0])
                (t_a, k_a), (t_b, k_b) = marks[0], marks[-1]
                measured[th] = (t_b - t_a) / (k_b - k_a)

            per: dict[int, list[float]] = {1: [], 2: []}
            for _ in range(max(2, rounds // 2)):
                for th in (1, 2):
                    roll(th)
                    per[th].append(measured[th])
            t1, t2 = min(per[1]), min(per[2])
            loop = "compiled loop" if spec.startswith("compiled") else "Python loop"
            print(f"| rollout ({loop}) {spec.split()[-1]}, rig, N = {n}: one control period (all envs) | "
                  f"{1e6 * t1:.0f} us | {1e6 * t2:.0f} us | {t1 / t2:.2f} | (not measured) |")
    print(f"\nload average after: {_loadavg()}")


def _period_us(scene, spec: str, n: int, n_steps: int, repeats: int, compiled: bool = False) -> float:
    """Wall time (us) of one control period per env of a rollout as compare runs it, between the
    rollout's first progress report and its last (the episodes' resets are left out)."""
    from impact_env.eval.rollout import rollout
    from impact_env.policy.export import export_policy
    from impact_env.policy.registry import make_policy

    pol = export_policy(spec, scene) if compiled else make_policy(spec, scene)
    best = np.inf
    for _ in range(repeats):
        marks: list[tuple[float, int]] = []
        done = [0]

        def progress(k, marks=marks, done=done):
            done[0] += k
            marks.append((time.perf_counter(), done[0]))

        rollout(scene, pol, range(n), horizon=n_steps * scene.control_period, trace_rate=1e4,
                progress=progress, trace_rows=[0])  # (compare keeps episode 0's traces)
        (t_a, k_a), (t_b, k_b) = marks[0], marks[-1]
        best = min(best, (t_b - t_a) / (k_b - k_a) / n)
    return best * 1e6


def period_table(quick: bool) -> None:
    from impact_env.config import with_overrides

    n = 100 if quick else 400
    n_steps = 500 if quick else 4000
    repeats = 1 if quick else 3
    rig = impact_env.load_scene("rig")
    old = with_overrides(rig, {"integrator.method": "rk4", "integrator.dt": 1e-6})
    print(f"\n## The batched control period (rollout of rig, N = {n}, {n_steps} periods, one thread)\n\n"
          f"(load average before: {_loadavg()})\n")
    print(f"| policy (loop) | default integrator ({rig.integrator.method}) us per env per period | "
          "RK4 at 1 us | ratio |")
    print("|---|---|---|---|")
    for spec, compiled in (("passive", False), ("pd-penetration", False), ("pd-penetration", True)):
        new_us = _period_us(rig, spec, n, n_steps, repeats, compiled)
        old_us = _period_us(old, spec, n, n_steps, repeats, compiled)
        loop = "compiled loop" if compiled else "Python loop"
        print(f"| {spec} ({loop}) | {new_us:.2f} | {old_us:.2f} | {old_us / new_us:.2f}x faster |")
    print(f"\ngoal: <= 0.3 us per env per period (load average after: {_loadavg()})")


def period_parts(quick: bool) -> None:
    """What the batched control period is made of: compare's rollout of ``passive`` on ``rig``
    with the scene's effects switched on one at a time (``effects.active``, in the order they
    act), then ``pd-penetration`` compiled and in Python: each row's cost less the row above it
    is that part's.  The first row is the plant with the rollout's own work (records, metrics,
    the loop)."""
    from impact_env.config import with_overrides

    n, n_steps, repeats = (100, 500, 1) if quick else (400, 4000, 3)
    rig = impact_env.load_scene("rig")
    stages = rig.effects.active
    print(f"\n## What the control period is made of (rollout of rig, N = {n}, {n_steps} periods, one thread)"
          f"\n\n(load average before: {_loadavg()})\n")
    print("| what runs | us per env per period | this part |")
    print("|---|---|---|")
    rows = [(f"passive, effects: {', '.join(stages[:k]) or 'none (the plant, records, metrics, the loop)'}",
             with_overrides(rig, {"effects.active": list(stages[:k])}), "passive", False)
            for k in range(len(stages) + 1)]
    rows += [("pd-penetration, compiled loop (+ the law)", rig, "pd-penetration", True),
             ("pd-penetration, Python loop (+ a Python call per period)", rig, "pd-penetration", False)]
    before = 0.0
    for name, scene, spec, compiled in rows:
        us = _period_us(scene, spec, n, n_steps, repeats, compiled)
        print(f"| {name} | {us:.3f} | {us - before:+.3f} |")
        before = us if compiled or spec == "passive" else before
    print(f"\n(load average after: {_loadavg()})")


def step_breakdown(repeats: int = 7) -> None:
    """Where one step of ``gymnasium.make("ImpactCatch-v0", scene="rig")`` goes, each part timed
    alone (min over repeats), beside ``MountainCarContinuous-v0``'s whole step; and a vector
    env's reset per env (every episode of ``rig`` draws its drop).  The parts that advance the
    env (the whole step, the compiled step's work) are timed over the first 3000 steps after
    ``reset(seed=0)`` in every repeat (the same work: a step's cost changes along an episode).
    The last row is the whole step less the parts, each timed alone: on a busy machine (or with
    ``--quick``'s few repeats) it can come out negative."""
    from impact_env.env.task import info_from_row
    from impact_env.env.vector import ImpactCatchVectorEnv

    def us(f, reps=20000, before=None):
        best = np.inf
        for _ in range(repeats):
            if before is not None:
                before()
            t0 = time.perf_counter()
            for _ in range(reps):
                f()
            best = min(best, (time.perf_counter() - t0) / reps)
        return 1e6 * best

    load = _loadavg()
    a32 = np.array([0.1], np.float32)
    mc = gym.make("MountainCarContinuous-v0")
    mc.reset(seed=0)
    env = gym.make("ImpactCatch-v0", scene="rig")
    env.reset(seed=0)
    task = env.unwrapped.task
    sim = task.sim
    rows = [("MountainCarContinuous-v0: a whole step (gymnasium.make)", us(lambda: mc.step(a32)))]
    def fresh():
        env.reset(seed=0)

    whole = us(lambda: env.step(a32), 3000, fresh)
    inner = us(lambda: env.unwrapped.step(a32), 3000, fresh)
    fresh()
    a = task.check_actions(a32)
    args = sim.step_args(a) + (task.drop, task.params, task.state, task.out, task._no_cols)
    off = (a, np.zeros(1, dtype=bool)) + args[2:]

    run = task._run  # the BlockRunner, as the step calls it

    def kernel():
        sim.hw.refill_noise(1)
        run(sim.blocks, args)

    tick = us(kernel, 3000, fresh) - us(lambda: run(sim.blocks, off))
    rows += [("ImpactCatch-v0 rig: a whole step (gymnasium.make)", whole),
             ("  the wrappers (gymnasium.make's checker, order enforcing)", whole - inner),
             ("  the compiled step's work (one control period of one env: plant, effects, front "
              "end, records, task)", tick),
             ("  the compiled step's call through its BlockRunner, on an inactive env (its ~50 arrays "
              "and ~25 scalars unboxed)", us(lambda: run(sim.blocks, off))),
             ("  the info dict (info_from_row)", us(lambda: info_from_row(task.rows[0]))),
             ("  the observation's copy", us(lambda: task.obs[0].copy())),
             ("  the action's check", us(lambda: task.check_actions(a32))),
             ("  Simulator.step_args (arrays' checks, the noise's top-up check)",
              us(lambda: sim.step_args(a)))]
    rest = inner - sum(x for _, x in rows[3:])
    rows.append(("  the rest of ImpactCatchEnv.step's Python (its calls, the tuple)", rest))
    print(f"\n## One step of the single env, part by part (us, min over repeats)\n\n(load average "
          f"before: {load}, after: {_loadavg()})\n")
    print("| part | us |")
    print("|---|---|")
    for name, x in rows:
        print(f"| {name} | {x:.2f} |")
    n = 1024
    venv = ImpactCatchVectorEnv(n, "rig")
    venv.reset(seed=0)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        venv.reset()
        best = min(best, time.perf_counter() - t0)
    print(f"\nvector env reset on rig (every env draws its drop), N = {n}: {1e6 * best / n:.0f} us per env")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and repeats (a smoke run)")
    ap.add_argument("--only", choices=("ratios", "threads", "vector-threads", "period", "period-parts",
                                       "step"),
                    help="run only this section")
    args = ap.parse_args()
    impact_env.load_scene("rig")
    if args.only == "threads":
        threads_table(args.quick)
        return
    if args.only == "vector-threads":
        vector_threads_table(args.quick)
        return
    if args.only == "step":
        step_breakdown()
        return
    if args.only == "period":
        period_table(args.quick)
        return
    if args.only == "period-parts":
        period_parts(args.quick)
        return
    n_steps, repeats = (500, 2) if args.quick else (3000, 5)
    print(f"(load average before: {_loadavg()})")
    single_env_table(n_steps, repeats)
    if args.only != "ratios":
        step_breakdown(3 if args.quick else 7)
    vector_table((1, 64, 1024) if args.quick else (1, 64, 1024, 4096), 20 if args.quick else 100,
                 2 if args.quick else 3)
    if args.only == "ratios":
        print(f"\n(load average after: {_loadavg()})")
        return
    ppo_share(8192 if args.quick else 32768)
    period_table(args.quick)
    period_parts(args.quick)
    threads_table(args.quick)


if __name__ == "__main__":
    main()
