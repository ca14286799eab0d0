"""``pd-penetration``: the policy class of the law :mod:`impact_env.control.laws.pd_penetration`
(its docs are there); this module keeps its old import path."""

from impact_env.policy.laws import LAW_POLICIES

PDPenetration = LAW_POLICIES["pd-penetration"]

__all__ = ["PDPenetration"]
