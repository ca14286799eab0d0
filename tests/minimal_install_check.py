"""The core install, without the optional extras (run by .ci/run in a venv of its own, after
``pip install -e .`` alone): importing impact_env, making and checking the env, a classic-law
comparison, a drop and an export work without torch and stable-baselines3, and a saved model
is refused with the install hint.  Not a pytest module: the dev venv has every extra."""

from __future__ import annotations

import importlib.util
import subprocess
import sys


def main() -> int:
    for mod in ("torch", "stable_baselines3"):
        assert importlib.util.find_spec(mod) is None, f"{mod} is installed: this is not a core-only venv"
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import impact_env  # noqa: F401  (registers the envs)

    env = gym.make("ImpactCatch-v0")
    check_env(env.unwrapped)
    run = [sys.executable, "-m", "impact_env.cli.main"]
    out = subprocess.run([*run, "compare", "--scene", "rig", "--policies",
                          "passive,pd-penetration,thesis-rig", "--episodes", "4", "--horizon", "0.05",
                          "--workers", "1", "--no-progress"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "pd-penetration" in out.stdout, out.stderr[-2000:]
    out = subprocess.run([*run, "drop", "--scene", "rig", "--json"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0 and "max_penetration_m" in out.stdout, out.stderr[-2000:]
    out = subprocess.run([*run, "compare", "--policies", "ppo:agents/models/best/model.zip",
                          "--episodes", "1"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "impact-env[sb3]" in out.stderr, out.stderr[-2000:]
    print("minimal install check OK: the env checker, a classic-law compare and a drop ran without torch "
          "and stable-baselines3; a saved model refused with the install hint")
    return 0


if __name__ == "__main__":
    sys.exit(main())
