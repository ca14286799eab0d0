"""Evaluation: rollouts of policies on seeded drops (:mod:`~impact_env.eval.rollout`), the
comparison table and its plots (:mod:`~impact_env.eval.compare`), gain sweeps
(:mod:`~impact_env.eval.sweep`), the process pool they share (:mod:`~impact_env.eval.parallel`), and
the per-drop open-loop optimum that compare uses as its yardstick (:mod:`~impact_env.eval.oracle`)."""
