"""Trained agents (PPO, SAC from stable-baselines3) against ``ImpactCatch-v0``.

Train (``agents/train.py``; hyperparameters and why in its ``PPO_DEFAULTS`` / ``SAC_DEFAULTS``)::

    python -m agents.train --algo ppo --scene rig --steps 6000000 --envs 16 --seed 0 \\
        --history 4 --out agents/models/ppo_rig

or from Python: ``agents.train.train("ppo", "rig", steps=..., envs=16, seed=0, out=DIR)``.  Both
write ``DIR/model.zip`` (the SB3 model, no ``VecNormalize``: the env's observations are already of
order one) and ``DIR/model.json`` (observation, history, algo, scene, overrides, steps, seed, wall
time, hyperparameters), which :mod:`baselines.sb3` reads, so the model joins the comparison::

    impact-env compare --scene rig --policies passive,pd-penetration,ppo:agents/models/ppo_rig/model.zip \\
        --episodes 100 --seed 1000

(seed 1000 and up: drops that training, seeded 0..envs-1, did not start from).
"""
