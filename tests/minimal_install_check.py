"""The core install, without the optional extras (run by .ci/run in a venv of its own, after
``pip install -e .`` alone): importing impact_env, making and checking the env, a classic-law
comparison, a drop and an export work without torch and stable-baselines3, and a saved model
is refused with the install hint, and so is training (``python -m agents.train``: stable-baselines3,
torch and PyYAML are the extra 'sb3') and ``--cluster`` (Dask: the extra 'cluster').  Not a pytest
module: the dev venv has every extra."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path


def main() -> int:
    for mod in ("torch", "stable_baselines3", "yaml"):
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
    # training needs the extra (stable-baselines3, torch, PyYAML for its YAML files): one line saying so
    out = subprocess.run([sys.executable, "-m", "agents.train", "--algo", "ppo", "--out", "runs/never"],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "impact-env[sb3]" in out.stderr and "Traceback" not in out.stderr, \
        out.stderr[-2000:]
    assert not Path("runs/never").exists()
    # a cluster needs the extra 'cluster' (Dask distributed), imported only when --cluster is given
    assert importlib.util.find_spec("distributed") is None, "distributed is installed: not a core-only venv"
    out = subprocess.run([*run, "compare", "--scene", "rig", "--policies", "passive", "--episodes", "1",
                          "--cluster", "tcp://127.0.0.1:8786"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "impact-env[cluster]" in out.stderr and "--cluster" in out.stderr \
        and "Traceback" not in out.stderr, out.stderr[-2000:]
    print("minimal install check OK: the env checker, a classic-law compare and a drop ran without torch "
          "and stable-baselines3; a saved model, training and --cluster refused with the install hint")
    return 0


if __name__ == "__main__":
    sys.exit(main())
