"""The cases whose outputs are recorded as golden files (``tests/golden/*.npz``).

``python scripts/record_golden.py`` runs every case and writes its arrays; ``tests/test_golden.py``
runs them again and asks for bitwise equality (``np.array_equal`` with NaN equal to NaN).  They
were recorded before the "rig-shaped core" refactor, so that refactor is proven to change no
simulated number.  Cases use only public entry points (``gymnasium.make``, ``impact_env.simulate``,
the compare function), so that they survive moves inside the package.

Bitwise equality is defined on the machine that recorded the files: scipy's ``expm`` (the
shaker's exact discretisation) and LAPACK (the pad damping's fit, the filters' design) use BLAS
kernels that differ between CPUs in the last bit, and an impact amplifies a last-bit difference.
The files therefore carry a fingerprint (the CPU name and features numba compiles for, numpy's
and scipy's versions); :func:`fingerprint` is compared before the arrays, and elsewhere the
test allows each array what the integration resolves (``tests/test_golden.py``): every case can
run with its integrator's tolerance loosened (``run_case(name, loosen)``).
"""

from __future__ import annotations

import math

import numpy as np

EPISODE_CASES = {
    # name: (scene, overrides, env kwargs, reset seeds, action seed)
    "rig_sensors": ("rig", None, {}, (3, 11), 7),
    "rig_both_history3": ("rig", None, {"observation": "both", "history": 3}, (4,), 8),
    "rig_randomized": ("rig-randomized", None, {}, (5, 6), 9),
    "ideal_privileged_10khz": ("ideal", {"control.rate": 1e4}, {"observation": "privileged"}, (6,), 10),
}
VECTOR_CASES = {
    # name: (scene, autoreset mode, num envs, steps, seed)
    "vector_next_step": ("rig", "NextStep", 3, 900, 21),
    "vector_same_step": ("rig-randomized", "SameStep", 3, 900, 22),
}
COMPARE_CASES = {
    # name: (scene, overrides, policies, episodes, seed, horizon s)
    "compare_rig": ("rig", None, ("passive", "thesis-rig", "pd-penetration", "thesis-ideal",
                                  "ppo:agents/models/ppo_rig/model.zip"), 4, 0, None),
    "compare_rig_randomized": ("rig-randomized", None, ("passive", "thesis-rig", "pd-penetration"), 4, 100,
                               None),
    "compare_ideal": ("ideal", None, ("passive", "thesis-ideal"), 2, 0, 0.004),
    # the solver laws: the MPC on the true state and on the filter's estimate
    "compare_rig_mpc": ("rig", None, ("mpc-state", "mpc"), 2, 1000, None),
}
DROP_CASES = {
    # name: (scene, overrides, t_end s, record rate Hz, rng seed)
    "drop_ideal_rk4": ("ideal", None, 0.01, 1e5, None),
    "drop_ideal_euler": ("ideal", {"integrator.method": "euler", "integrator.dt": 1e-6}, 0.01, 1e5, None),
    "drop_ideal_symplectic": ("ideal", {"integrator.method": "symplectic-euler"}, 0.01, 1e5, None),
    "drop_ideal_dopri5": ("ideal", {"integrator.method": "dopri5", "control.rate": 1e5}, 0.01, 1e5, None),
    "drop_ideal_rk4_no_events": ("ideal", {"integrator.event_location": False}, 0.01, 1e5, None),
    "drop_rig": ("rig", None, None, None, None),
    "drop_rig_randomized": ("rig-randomized", None, 0.1, None, 3),
}
TRAJECTORY_KEYS = ("t", "x1", "v1", "x2", "v2", "contact", "contact_force", "peak_force", "shaker_force",
                   "work_shaker", "dissipated", "events")


def fingerprint() -> dict[str, str]:
    """What bitwise equality depends on besides the code: the CPU numba compiles for and the
    versions of the numerical libraries."""
    import llvmlite.binding as llvm
    import numba
    import scipy

    return {"cpu": llvm.get_host_cpu_name(), "features": llvm.get_host_cpu_features().flatten(),
            "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__}


def _loosened(scene, ov, loosen: float):
    """``ov`` with the integrator's tolerance of ``scene`` (with ``ov``) times ``loosen``."""
    if loosen == 1.0:
        return ov
    from impact_env.scene import load_scene

    return {**(ov or {}), "integrator.rtol": load_scene(scene, ov).integrator.rtol * loosen}


def episode_case(name: str, loosen: float = 1.0) -> dict[str, np.ndarray]:
    """Whole episodes of one single env: observation, reward, flags and info after every step,
    under uniform random actions from a seeded Generator."""
    import gymnasium as gym

    import impact_env  # noqa: F401  (registers the env)

    scene, ov, kwargs, seeds, action_seed = EPISODE_CASES[name]
    ov = _loosened(scene, ov, loosen)
    env = gym.make("ImpactCatch-v0", scene=scene, overrides=ov, **kwargs).unwrapped
    rng = np.random.default_rng(action_seed)
    obs_l, rew, flags, infos = [], [], [], []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        obs_l.append(obs)
        infos.append(_info_row(info))
        rew.append(math.nan)
        flags.append((0, 0))
        while True:
            obs, r, te, tr, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
            obs_l.append(obs)
            rew.append(r)
            flags.append((te, tr))
            infos.append(_info_row(info))
            if te or tr:
                break
    return {"obs": np.array(obs_l), "reward": np.array(rew), "flags": np.array(flags, dtype=np.int8),
            "info": np.array(infos)}


INFO_KEYS = ("t", "catch_energy", "catch_energy_ratio", "impact_energy", "impact_speed", "contact",
             "contact_force", "force_demand", "force_applied", "saturated", "detected", "diverged", "caught",
             "t_touch")


def _info_row(info) -> list[float]:
    return [float(info[k]) for k in INFO_KEYS] + [float(x) for x in info["state"]]


def vector_case(name: str, loosen: float = 1.0) -> dict[str, np.ndarray]:
    """The native vector env through autoresets (short episodes: horizon 0.03 s)."""
    from gymnasium.vector import AutoresetMode

    import impact_env  # noqa: F401

    scene, mode, n, steps, seed = VECTOR_CASES[name]
    import gymnasium as gym

    venv = gym.make_vec("ImpactCatch-v0", num_envs=n, vectorization_mode="vector_entry_point", scene=scene,
                        overrides=_loosened(scene, None, loosen), autoreset_mode=AutoresetMode(mode),
                        horizon=0.03)
    rng = np.random.default_rng(seed)
    obs, info = venv.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "info": [], "final_obs": []}
    for _ in range(steps):
        obs, r, te, tr, info = venv.step(rng.uniform(-1, 1, (n, 1)).astype(np.float32))
        out["obs"].append(obs)
        out["reward"].append(r)
        out["terminated"].append(te)
        out["truncated"].append(tr)
        out["info"].append(np.column_stack([np.asarray(info[k], dtype=np.float64) for k in INFO_KEYS]
                                           + [info["state"]]))
        if "final_obs" in info:
            fo = np.full((n, obs.shape[1]), np.nan)
            for i in np.nonzero(info["_final_obs"])[0]:
                fo[i] = info["final_obs"][i]
            out["final_obs"].append(fo)
    return {k: np.array(v) for k, v in out.items()}


def compare_case(name: str, loosen: float = 1.0) -> dict[str, np.ndarray]:
    """Every per-episode metric of every policy, and episode 0's traces."""
    from impact_env.eval.compare import compare
    from impact_env.scene import load_scene

    scene, ov, specs, episodes, seed, horizon = COMPARE_CASES[name]
    runs = compare(load_scene(scene, _loosened(scene, ov, loosen)), list(specs), episodes=episodes, seed=seed,
                   horizon=horizon, workers=1, progress=False)
    out = {}
    for j, spec in enumerate(specs):
        run = runs[spec]
        for key, v in run.metrics.items():
            out[f"p{j}/{key}"] = np.asarray(v)
        for key, v in (run.trace0 or {}).items():
            out[f"p{j}/trace0/{key}"] = np.asarray(v)
        out[f"p{j}/energy_ratio"] = np.asarray(run.energy_ratio)
    return out


def drop_case(name: str, loosen: float = 1.0) -> dict[str, np.ndarray]:
    """One simulated drop: every Trajectory array and its metrics (wall time left out)."""
    import impact_env

    scene, ov, t_end, rate, seed = DROP_CASES[name]
    ov = _loosened(scene, ov, loosen)
    tr = impact_env.simulate(scene, t_end=t_end, record_rate=rate, overrides=ov, rng=seed, plant_only=True)
    out = {k: np.asarray(getattr(tr, k)) for k in TRAJECTORY_KEYS}
    m = tr.metrics()
    m.pop("wall_time_s", None)
    m.pop("warnings", None)  # words, not numbers
    for k, v in m.items():
        out[f"metric/{k}"] = np.asarray(np.nan if v is None else v, dtype=np.float64)
    return out


def float32_policy_array(name: str, key: str) -> bool:
    """Whether array ``key`` of case ``name`` comes from a policy network that computes in
    float32 (an SB3 model through torch): its command is then a float32 number, which another
    instruction set may round one ulp apart (torch picks its matrix kernels by CPU: measured,
    a peak demand 1.19e-5 N apart on 167 N, one float32 ulp of the action times 200 N, between a
    Zen 3 and an AVX-512 Rocket Lake, where no loosening of the integrator moves it)."""
    if name not in COMPARE_CASES or not key.startswith("p"):
        return False
    from impact_env.policy.registry import is_model_spec

    j = int(key[1:].partition("/")[0])
    return is_model_spec(COMPARE_CASES[name][2][j])


CASES = {**{k: episode_case for k in EPISODE_CASES}, **{k: vector_case for k in VECTOR_CASES},
         **{k: compare_case for k in COMPARE_CASES}, **{k: drop_case for k in DROP_CASES}}


def run_case(name: str, loosen: float = 1.0) -> dict[str, np.ndarray]:
    """Case ``name``'s arrays; ``loosen``: its integrator's tolerance times this (1: as recorded)."""
    return CASES[name](name, loosen)
