"""Classic controllers (baselines) with the stable-baselines3 ``predict`` interface.

``make_policy("thesis-rig:h01=2.3e6,h11=18", scene)`` builds one by name; ``POLICIES`` lists
them, one class per law of :mod:`impact_env.control.laws` (each law's docs, gains and kernel are
its module there).  Every policy has ``observation`` ("sensors" or "privileged"), and
``predict(obs, state=None, episode_start=None, deterministic=True) -> (action, state)`` with
actions clipped to the env's [-1, 1] (see :mod:`impact_env.policy.laws`).
"""

from baselines.base import Param, Policy
from baselines.passive import Passive
from baselines.pd_penetration import PDPenetration
from baselines.registry import POLICIES, make_policy, parse_spec
from baselines.thesis_ideal import ThesisIdeal
from baselines.thesis_rig import ThesisRig

__all__ = ["POLICIES", "PDPenetration", "Param", "Passive", "Policy", "ThesisIdeal", "ThesisRig",
           "make_policy", "parse_spec"]
