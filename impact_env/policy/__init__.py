"""Policies as the rest of the project sees them: the registry of named policies
(:mod:`~impact_env.policy.registry`) and saved stable-baselines3 models
(:mod:`~impact_env.policy.sb3`)."""
