"""The classic laws of this package by name: one policy class per law of
:data:`impact_env.control.laws.REGISTRY` (:data:`impact_env.policy.laws.LAW_POLICIES`), which
:mod:`impact_env.policy.registry` (``impact-env compare``) finds without entry points;
``make_policy`` and ``parse_spec`` are re-exported here for convenience.
"""

from __future__ import annotations

from impact_env.policy.laws import LAW_POLICIES, Policy
from impact_env.policy.registry import describe_policies, is_model_spec, make_policy, parse_spec

POLICIES: dict[str, type[Policy]] = dict(LAW_POLICIES)

__all__ = ["POLICIES", "describe_policies", "is_model_spec", "make_policy", "parse_spec"]
