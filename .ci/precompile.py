"""The kernels most of the suite needs, compiled once before pytest's workers start (run by
.ci/run; the cache in ``NUMBA_CACHE_DIR`` is shared by every venv of the run).

    python .ci/precompile.py core|rig|oracle

On a cold cache each worker (and each rig target a test starts) would otherwise compile the same
kernels at once on the same cores: a compile log of the suite (``IMPACT_ENV_COMPILE_LOG``,
scripts/suite_compile_report.py) showed the compiled-policy loop and the oracle's replay
compiled in two processes each, about 130 s and 70 s of a core every time, and a rig target's
warm-up compiles about 150 s of kernels of its own.

* ``core``: what the core install runs, so .ci/run compiles it in the core venv while the
  development venv is still installing: the env's step, compare's Python-policy loop with the
  laws (mpc's solver and filter), then the compiled-policy loop (``sim.step.step_env``, one
  signature for every exported law or agent), serial and in threads;
* ``rig``: the rig target's controller and real-time loop (a lock-step virtual rig's warm-up;
  h5py, the extra 'rig');
* ``oracle``: the oracle's search and replay (cma, the extra 'oracle'), after ``core``: its replay
  calls the per-env step that ``core`` compiles.
"""

import sys

from impact_env.scene import load_scene


def core() -> None:
    import gymnasium as gym

    import impact_env  # noqa: F401  (registers the env)
    from impact_env.eval.compare import compare
    from impact_env.eval.rollout import MIN_BLOCK_EPISODES, rollout
    from impact_env.policy.export import export_policy

    environment = gym.make("ImpactCatch-v0")
    environment.reset(seed=0)
    environment.step(environment.action_space.sample())
    scene = load_scene("rig")
    compare(scene, ["passive", "mpc"], episodes=2, seed=0, horizon=0.015, workers=1, progress=False)
    policy = export_policy("pd-penetration", scene)
    rollout(scene, policy, [0, 1], horizon=2 * scene.control_period, trace_rate=0.0)
    # the threaded loop (one compiled parallel region over blocks of episodes): compare --threads,
    # tests/test_threads.py and the TBB layer's check
    rollout(scene, policy, list(range(2 * MIN_BLOCK_EPISODES)), horizon=2 * scene.control_period,
            trace_rate=0.0, threads=2)


def rig() -> None:
    from impact_env.rig.driver import VirtualRig
    from impact_env.rig.target import Target, TargetConfig

    Target(VirtualRig("rig"), config=TargetConfig(lockstep=True)).close()  # it warms up as it starts


def oracle() -> None:
    from impact_env.eval.compare import compare

    compare(load_scene("rig"), ["oracle:generations=1,popsize=2"], episodes=2, seed=0, horizon=0.015,
            workers=1, progress=False)


if __name__ == "__main__":
    parts = {"core": core, "rig": rig, "oracle": oracle}
    if len(sys.argv) != 2 or sys.argv[1] not in parts:
        raise SystemExit(f"usage: python .ci/precompile.py {'|'.join(parts)}")
    parts[sys.argv[1]]()
