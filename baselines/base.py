"""The policy interface shared by every baseline (stable-baselines3's ``predict``) lives in
:mod:`impact_env.policy.laws`; this module keeps its old import path."""

from impact_env.control.laws.law import Param
from impact_env.policy.laws import Policy

__all__ = ["Param", "Policy"]
