"""The kernels most of the suite needs, compiled once before pytest's workers start (run by
.ci/run; the cache in ``NUMBA_CACHE_DIR`` is shared by every venv of the run).

    python .ci/precompile.py PART [PART ...]     (shared, env, rollout, rig, rig-rest, oracle)

Each part, once compiled, leaves the marker file ``.ci/out/precompiled-PART``, which the other
lanes of .ci/run wait for.

On a cold cache each worker (and each rig target a test starts) would otherwise compile the same
kernels at once on the same cores: a compile log of the suite (``IMPACT_ENV_COMPILE_LOG``,
scripts/suite_compile_report.py) showed the compiled-policy loop and the oracle's replay
compiled in two processes each, about 130 s and 70 s of a core every time, and a rig target's
warm-up compiles about 150 s of kernels of its own.  .ci/run compiles ``env`` then ``rollout``
in one process and ``rig`` then ``rig-rest`` in another at once, after ``shared``, so no two
processes compile the same kernel.

* ``shared``: what the later parts all call, first: the hardware tick
  (``hardware.stage.hardware_step``) with the plant's integrators it calls
  (``plant.integrators.advance``, about 55 s of a core), which the env's step calls too, and the
  classic laws' kernels (``control.laws.law_forces``: the model-predictive laws' solver and
  estimator, about 30 s), which the env's step, the compiled-policy loop and the rig target's
  tick call;
* ``env``: what the core install runs, in the core venv while the development venv is still
  installing: the env's step and compare's Python-policy loop with the laws;
* ``rollout``: the compiled-policy loop (one signature for every exported law or agent), serial
  and in threads (``compare --threads``, tests/test_threads.py, the TBB layer's check), after
  ``env``: it calls the env's step (``sim.step.sim_step``) that ``env`` compiles;
* ``rig``: the rig target's controller and real-time loop (a lock-step virtual rig's warm-up;
  h5py, the extra 'rig');
* ``rig-rest``: what the suite's tests still compiled themselves (the cache's files written
  during a CI run's suite): the real-time loop for a driver called by address (a Python driver
  here, as tests/rig_drivers.py's), the host's compiled exchange and its loop for a policy on the
  host (``RigClient.run_policy``), and the hardware replay of the
  identification, with and without the delay effects;
* ``oracle``: the oracle's search and replay (cma, the extra 'oracle'), after ``rollout``: its
  search rolls out the classic laws in the compiled-policy loop.
"""

import sys
from pathlib import Path

from impact_env.scene import load_scene

MARKERS = Path(__file__).resolve().parent / "out"


def shared() -> None:
    import numpy as np

    from impact_env.control.laws import LAWS, MEMORY, N_SLOTS, law_forces
    from impact_env.hardware.batch import Hardware

    hardware = Hardware(load_scene("rig"), 1)
    hardware.reset([np.random.default_rng(0)])
    hardware.step(np.zeros(1))
    # passive (kind 0) computes nothing; the call compiles every law's branch, for rows of
    # C-contiguous float64 arrays as the env's step and the policies pass them
    law_forces(LAWS.index("passive"), np.zeros(N_SLOTS, dtype=np.int64), np.zeros((1, 64)),
               np.zeros((1, 64)), np.zeros((1, MEMORY)), np.zeros(1))


def env() -> None:
    import gymnasium as gym

    import impact_env  # noqa: F401  (registers the env)
    from impact_env.eval.compare import compare

    environment = gym.make("ImpactCatch-v0")
    environment.reset(seed=0)
    environment.step(environment.action_space.sample())
    compare(load_scene("rig"), ["passive", "mpc"], episodes=2, seed=0, horizon=0.015, workers=1,
            progress=False)


def rollout() -> None:
    from impact_env.eval.rollout import MIN_BLOCK_EPISODES
    from impact_env.eval.rollout import rollout as run
    from impact_env.policy.export import export_policy

    scene = load_scene("rig")
    policy = export_policy("pd-penetration", scene)
    run(scene, policy, [0, 1], horizon=2 * scene.control_period, trace_rate=0.0)
    # the threaded loop (one compiled parallel region over blocks of episodes)
    run(scene, policy, list(range(2 * MIN_BLOCK_EPISODES)), horizon=2 * scene.control_period,
        trace_rate=0.0, threads=2)


def rig() -> None:
    from impact_env.rig.driver import VirtualRig
    from impact_env.rig.target import Target, TargetConfig

    Target(VirtualRig("rig"), config=TargetConfig(lockstep=True)).close()  # it warms up as it starts


def rig_rest() -> None:
    import threading

    import numpy as np

    from impact_env.hardware.batch import Hardware
    from impact_env.hardware.replay import replay
    from impact_env.policy.export import export_policy
    from impact_env.rig.driver import VirtualRig
    from impact_env.rig.host import RigClient
    from impact_env.rig.target import Target, TargetConfig

    sys.path.insert(0, "tests")
    from rig_drivers import BlindRig  # a Python driver, which the loop calls through ctypes callbacks

    Target(BlindRig("rig"), config=TargetConfig(lockstep=True)).close()
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True))
    serving = threading.Thread(target=target.serve, daemon=True)
    serving.start()
    client = RigClient(target.address)  # the client compiles its exchange as it connects
    # a policy compiled on the host
    client.run_policy(export_policy("pd-penetration", target.scene), seed=0, n_steps=2)
    client.close()
    target.stop()
    serving.join(10)
    # a replay's drops are fixed: no drawn mass or height
    base = load_scene("rig").with_overrides({"randomize.m1": [], "randomize.drop_height": []})
    delayed = base.with_overrides({"effects.active": [*base.effects.active, "actuator_delay", "sensor_delay"],
                                   "effects.delay.actuator_s": 2e-4, "effects.delay.sensor_s": 3e-4})
    for scene in (base, delayed):
        replay(Hardware(scene, 1), np.zeros(8))


def oracle() -> None:
    from impact_env.eval.compare import compare

    compare(load_scene("rig"), ["oracle:generations=1,popsize=2"], episodes=2, seed=0, horizon=0.015,
            workers=1, progress=False)


if __name__ == "__main__":
    parts = {"shared": shared, "env": env, "rollout": rollout, "rig": rig, "rig-rest": rig_rest,
             "oracle": oracle}
    if len(sys.argv) < 2 or not set(sys.argv[1:]) <= set(parts):
        raise SystemExit(f"usage: python .ci/precompile.py PART [PART ...] (parts: {', '.join(parts)})")
    MARKERS.mkdir(exist_ok=True)
    for name in sys.argv[1:]:
        parts[name]()
        (MARKERS / f"precompiled-{name}").touch()
