"""The Gymnasium layer: ``ImpactCatch-v0`` (single env), its native vector env and an SB3 adapter.

Importing :mod:`impact_env` registers ``ImpactCatch-v0`` with entry points given as strings, so
that nothing heavy (numba kernels, stable-baselines3) is imported or compiled until an env is
made.
"""

from __future__ import annotations

ENV_ID = "ImpactCatch-v0"
RIG_ENV_ID = "ImpactCatchRig-v0"


def register_envs() -> None:
    import gymnasium

    if RIG_ENV_ID not in gymnasium.registry:  # the rig's host-side env (impact_env.rig.host)
        gymnasium.register(id=RIG_ENV_ID, entry_point="impact_env.rig.host:RigEnv")
    if ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="impact_env.env.catch_env:ImpactCatchEnv",
        vector_entry_point="impact_env.env.vector:ImpactCatchVectorEnv",
        kwargs={"scene": "rig"},
    )
