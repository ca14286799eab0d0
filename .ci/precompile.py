"""The kernels most of the suite needs, compiled once in one process before pytest's workers start
(run by .ci/run, beside the layers, types and docs checks).  On a cold cache each worker would
otherwise compile the same kernels at once on the same cores: a compile log of the suite
(``IMPACT_ENV_COMPILE_LOG``, scripts/suite_compile_report.py) showed the compiled-policy loop and
the oracle's replay compiled in two processes each, about 130 s and 70 s of a core every time."""

import gymnasium as gym

import impact_env  # noqa: F401  (registers the env)
from impact_env.eval.compare import compare
from impact_env.eval.rollout import rollout
from impact_env.policy.export import export_policy
from impact_env.scene import load_scene

env = gym.make("ImpactCatch-v0")
env.reset(seed=0)
env.step(env.action_space.sample())
scene = load_scene("rig")
# the Python-policy loop, the laws (mpc's solver and filter), the oracle's search and replay
compare(scene, ["passive", "mpc", "oracle:generations=1,popsize=2"], episodes=2, seed=0, horizon=0.015,
        workers=1, progress=False)
# the compiled-policy loop: one signature for every exported law or agent
rollout(scene, export_policy("pd-penetration", scene), [0, 1], horizon=2 * scene.control_period,
        trace_rate=0.0)
