"""``thesis-ideal``: the policy class of the law :mod:`impact_env.control.laws.thesis_ideal`
(its docs are there); this module keeps its old import path."""

from impact_env.policy.laws import LAW_POLICIES

ThesisIdeal = LAW_POLICIES["thesis-ideal"]

__all__ = ["ThesisIdeal"]
