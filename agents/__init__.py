"""Trained agents (PPO, SAC from stable-baselines3) against ``ImpactCatch-v0``.

Train (``agents/train.py``; hyperparameters, with the reason for each, in the RL-Zoo-style files
``agents/hyperparams/ppo.yml`` and ``sac.yml``)::

    python -m agents.train --algo ppo --out runs/ppo0 --seed 0 [--hp learning_rate=1e-4] \\
        [--env-kwargs hold_ticks=4 --env-kwargs residual=pd-penetration] [--tensorboard runs/tb]

or from Python: ``agents.train.train("ppo", "rig", steps=..., envs=16, seed=0, out=DIR)``.  Both
write ``DIR/model.zip`` (the SB3 model, no ``VecNormalize``: the env's observations are already of
order one) and ``DIR/model.json`` (observation, history, algo, scene, overrides, env kwargs,
learnability options, steps, seed, wall time, hyperparameters), which :mod:`impact_env.policy.sb3`
reads, so a model trained without options joins the comparison::

    impact-env compare --scene rig --policies passive,pd-penetration,ppo:runs/ppo0/model.zip \\
        --episodes 100 --seed 1000

(seed 1000 and up: drops that training did not start from).  A model trained with the env's
``hold_ticks`` or ``residual`` options runs in compare with them (they are in ``model.json``), and
its compiled export too (``python -m agents.evaluate --model runs/x/model.zip --episodes 100
--seed 1000 --compiled``).  See docs/agents.md.
"""
