"""The classic laws of this package by name.

They are registered with :mod:`impact_env.policy.registry` through the entry-point group
``impact_env.policies`` (``pyproject.toml``), which is how ``impact-env compare`` finds them;
``make_policy`` and ``parse_spec`` are re-exported here for convenience.
"""

from __future__ import annotations

from baselines.base import Policy
from baselines.passive import Passive
from baselines.pd_penetration import PDPenetration
from baselines.thesis_ideal import ThesisIdeal
from baselines.thesis_rig import ThesisRig
from impact_env.policy.registry import describe_policies, is_model_spec, make_policy, parse_spec

POLICIES: dict[str, type[Policy]] = {
    cls.name: cls for cls in (Passive, ThesisIdeal, ThesisRig, PDPenetration)}

__all__ = ["POLICIES", "describe_policies", "is_model_spec", "make_policy", "parse_spec"]
