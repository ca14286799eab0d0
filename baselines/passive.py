"""``passive``: the policy class of the law :mod:`impact_env.control.laws.passive` (its docs are there);
this module keeps its old import path."""

from impact_env.policy.laws import LAW_POLICIES

Passive = LAW_POLICIES["passive"]

__all__ = ["Passive"]
