"""``thesis-rig``: the policy class of the law :mod:`impact_env.control.laws.thesis_rig` (its docs are there);
this module keeps its old import path."""

from impact_env.policy.laws import LAW_POLICIES

ThesisRig = LAW_POLICIES["thesis-rig"]

__all__ = ["ThesisRig"]
