"""Trained agents (PPO/SAC) against the impact_env environment."""
