"""A training run's settings: RL-Zoo-style YAML hyperparameters, validated before anything is built.

``agents/hyperparams/ppo.yml`` and ``sac.yml`` follow RL Zoo's format (rl_zoo3 2.9): one entry per
env id, here ``ImpactCatch-v0``, whose keys are the algorithm's constructor arguments plus RL
Zoo's special keys, which this module understands the same way:

* ``policy`` (``MlpPolicy``), ``n_envs``, ``n_timesteps`` (SB3 timesteps: policy steps; control
  periods when ``hold_ticks`` is 1);
* ``policy_kwargs`` (a mapping: ``net_arch``, ``log_std_init``, ``squash_output``, ``ortho_init``);
* ``env_kwargs``: the keyword arguments of ``gymnasium.make("ImpactCatch-v0", **env_kwargs)``
  (``scene``, ``overrides``, ``observation``, ``history``, ``horizon``, ``hold_ticks``,
  ``residual``, ``effort_weight``, ``terminate_on_catch``, ...): the learnability options are the
  env's own, so RL Zoo and ``agents.train`` build the same env from the same mapping;
* ``env_wrapper`` is refused (no wrapper is needed; the experimental wrappers of the first
  experiments are retired, their options are env kwargs now);
* ``learning_rate`` / ``clip_range`` as a number or RL Zoo's ``lin_<value>`` (linear decay to 0);
* ``normalize`` only ``false`` (the env's observations are already of order one; a model.zip is
  then the whole policy).

Every value is checked here with its expected type and range, so that a bad one is refused with
a message naming it before a folder is created or an env is built.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from impact_env.config import ConfigError

ENV_ID = "ImpactCatch-v0"
ALGOS = ("ppo", "sac")
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
ASYMMETRIC = "agents.policies.AsymmetricActorCriticPolicy"
ASYMMETRIC_SAC = "agents.policies.AsymmetricSACPolicy"
POLICIES = {"ppo": ("MlpPolicy", ASYMMETRIC), "sac": ("MlpPolicy", ASYMMETRIC_SAC)}
ZOO_KEYS = ("policy", "n_envs", "n_timesteps", "env_kwargs", "env_wrapper", "policy_kwargs", "normalize",
            "vec_env_wrapper")
ACTION_LIMIT = "impact_env.env.sb3_vecenv.ActionLimit"
# options of the first experiments that the env never took: refused with a pointer to docs/agents.md
RETIRED_KEYS = {"chatter_weight": "the chatter penalty did not help (docs/agents.md, e7) and was dropped; "
                                  "the env's effort_weight is its effort penalty"}


# -- value checks: each returns the value (possibly converted) or raises ConfigError -------------
def _err(key: str, value: Any, expected: str) -> ConfigError:
    return ConfigError(f"hyperparameter {key} = {value!r}: expected {expected}")


def _int(lo: int, hi: int | None = None, also: tuple = ()):
    rng = f">= {lo}" if hi is None else f"from {lo} to {hi}"
    extra = "".join(f" or {a!r}" for a in also)

    def check(key, v):
        if v in also and not isinstance(v, bool):
            return v
        if isinstance(v, float) and v.is_integer():
            v = int(v)  # YAML's 1e6 is a float
        if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
            raise _err(key, v, f"an integer {rng}{extra}")
        return v
    check.expected = f"int {rng}{extra}"
    return check


def _float(lo: float | None = None, hi: float | None = None, lo_open: bool = False, none: bool = False):
    parts = [s for s in ((f"> {lo:g}" if lo_open else f">= {lo:g}") if lo is not None else "",
                         f"<= {hi:g}" if hi is not None else "") if s]
    what = "a finite number" + (f" {' and '.join(parts)}" if parts else "") + (" or null" if none else "")

    def check(key, v):
        if v is None and none:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise _err(key, v, what)
        if lo is not None and (v <= lo if lo_open else v < lo) or hi is not None and v > hi:
            raise _err(key, v, what)
        return float(v)
    check.expected = what
    return check


def _bool(key, v):
    if not isinstance(v, bool):
        raise _err(key, v, "true or false")
    return v


_bool.expected = "bool"


def _schedule(key, v):
    """A positive number, or RL Zoo's ``lin_<positive number>``."""
    what = "a number > 0 (e.g. 3e-4) or a linear schedule 'lin_<number > 0>' (e.g. 'lin_3e-4')"
    x = v
    if isinstance(v, str) and v.startswith("lin_"):
        try:
            x = float(v[4:])
        except ValueError:
            raise _err(key, v, what) from None
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x <= 0:
        raise _err(key, v, what)
    return v if isinstance(v, str) else float(v)


_schedule.expected = "float > 0 or 'lin_<float>'"


def _ent_coef_sac(key, v):
    what = "a number >= 0, 'auto' or 'auto_<initial value > 0>'"
    if v == "auto":
        return v
    if isinstance(v, str) and v.startswith("auto_"):
        try:
            if float(v[5:]) > 0:
                return v
        except ValueError:
            pass
        raise _err(key, v, what)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise _err(key, v, what)
    return float(v)


_ent_coef_sac.expected = "float >= 0 or 'auto' / 'auto_<float>'"


def _target_entropy(key, v):
    if v == "auto":
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _err(key, v, "'auto' or a finite number")
    return float(v)


_target_entropy.expected = "'auto' or float"


def _train_freq(key, v):
    what = "an integer >= 1 or [integer >= 1, 'step' | 'episode']"
    if isinstance(v, (list, tuple)):
        first_ok = isinstance(v[0], int) and not isinstance(v[0], bool) and v[0] >= 1 if len(v) else False
        if len(v) == 2 and v[1] in ("step", "episode") and first_ok:
            return list(v)
        raise _err(key, v, what)
    return _int(1)(key, v)


_train_freq.expected = "int >= 1 or [int, 'step'|'episode']"


def _net_arch(dict_ok: bool):
    what = "a list of layer widths (integers >= 1), e.g. [64, 64]" + \
        (", or {pi: [...], vf: [...]}" if dict_ok else "")

    def layers(key, v):
        if not isinstance(v, (list, tuple)) or not all(
                isinstance(x, int) and not isinstance(x, bool) and x >= 1 for x in v):
            raise _err(key, v, what)
        return list(v)

    def check(key, v):
        if dict_ok and isinstance(v, dict):
            if set(v) != {"pi", "vf"}:
                raise _err(key, v, what)
            return {"pi": layers(key, v["pi"]), "vf": layers(key, v["vf"])}
        return layers(key, v)
    check.expected = what
    return check


_UNIT = _float(0.0, 1.0)
_GAMMA = _float(0.0, 1.0, lo_open=True)
PPO_SCHEMA = {
    "n_steps": _int(1), "batch_size": _int(2), "n_epochs": _int(1), "gamma": _GAMMA, "gae_lambda": _UNIT,
    "learning_rate": _schedule, "clip_range": _schedule,
    "clip_range_vf": _float(0.0, lo_open=True, none=True),
    "normalize_advantage": _bool, "ent_coef": _float(0.0), "vf_coef": _float(0.0),
    "max_grad_norm": _float(0.0, lo_open=True), "use_sde": _bool, "sde_sample_freq": _int(-1),
    "target_kl": _float(0.0, lo_open=True, none=True), "stats_window_size": _int(1),
}
SAC_SCHEMA = {
    "learning_rate": _schedule, "buffer_size": _int(1), "learning_starts": _int(0), "batch_size": _int(1),
    "tau": _float(0.0, 1.0, lo_open=True), "gamma": _GAMMA, "train_freq": _train_freq,
    "gradient_steps": _int(-1), "ent_coef": _ent_coef_sac, "target_update_interval": _int(1),
    "target_entropy": _target_entropy, "use_sde": _bool, "sde_sample_freq": _int(-1),
    "use_sde_at_warmup": _bool, "stats_window_size": _int(1), "n_steps": _int(1),
}
POLICY_SCHEMA = {"log_std_init": _float(-20.0, 5.0), "squash_output": _bool, "ortho_init": _bool,
                 "frame_size": _int(1), "actor_frame_size": _int(1), "history": _int(1, 64)}
SCHEMAS = {"ppo": PPO_SCHEMA, "sac": SAC_SCHEMA}


def check_hyperparameter(algo: str, key: str, value: Any) -> Any:
    """``value`` checked for hyperparameter (or policy kwarg) ``key`` of ``algo``."""
    schema = {**SCHEMAS[algo], **POLICY_SCHEMA, "net_arch": _net_arch(algo == "ppo")}
    if key not in schema:
        import difflib

        hint = difflib.get_close_matches(key, list(schema), n=1)
        near = f" (did you mean {hint[0]!r}?)" if hint else ""
        raise ConfigError(f"unknown {algo} hyperparameter {key!r}{near}; valid: {', '.join(schema)}")
    return schema[key](key, value)


# -- the resolved run ------------------------------------------------------------------------------
@dataclass
class RunConfig:
    """Everything a run needs, validated.  ``hyperparameters`` are the algorithm's keyword arguments
    (schedules still as strings), ``policy_kwargs`` the policy's; ``env_kwargs`` go to the native
    vector env (scene and overrides apart), ``hold_ticks`` and ``residual`` included."""

    algo: str
    scene: str
    overrides: dict
    env_kwargs: dict
    hyperparameters: dict
    policy_kwargs: dict
    n_envs: int
    n_timesteps: int
    seed: int
    conf_file: str | None = None
    policy: str = "MlpPolicy"
    extra: dict = field(default_factory=dict)
    action_limit: float | None = None  # ActionLimit's bound (YAML vec_env_wrapper), of the command scale

    @property
    def observation(self) -> str:
        return self.env_kwargs.get("observation", "sensors")

    @property
    def history(self) -> int:
        return int(self.env_kwargs.get("history", 1))

    @property
    def hold_ticks(self) -> int:
        return int(self.env_kwargs.get("hold_ticks", 1))

    @property
    def residual(self) -> str | None:
        return self.env_kwargs.get("residual")

    def to_dict(self) -> dict:
        return {"algo": self.algo, "scene": self.scene, "overrides": dict(self.overrides),
                "env_kwargs": dict(self.env_kwargs),
                "hyperparameters": dict(self.hyperparameters), "policy_kwargs": dict(self.policy_kwargs),
                "n_envs": self.n_envs, "n_timesteps": self.n_timesteps, "seed": self.seed,
                "conf_file": self.conf_file, "policy": self.policy, "action_limit": self.action_limit}

    @classmethod
    def from_dict(cls, d: dict) -> RunConfig:
        return cls(algo=d["algo"], scene=d["scene"], overrides=d["overrides"], env_kwargs=d["env_kwargs"],
                   hyperparameters=d["hyperparameters"], policy_kwargs=d["policy_kwargs"], n_envs=d["n_envs"],
                   n_timesteps=d["n_timesteps"], seed=d["seed"], conf_file=d.get("conf_file"),
                   policy=d.get("policy", "MlpPolicy"), action_limit=d.get("action_limit"))


def default_conf_file(algo: str) -> Path:
    return HYPERPARAMS_DIR / f"{algo}.yml"


def read_conf(path: str | Path, env_id: str = ENV_ID) -> dict:
    """The entry for ``env_id`` in an RL-Zoo-style YAML file (a copy)."""
    import yaml

    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"--conf-file {str(p)!r}: no such file")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"--conf-file {str(p)!r} is not valid YAML: {exc}") from None
    if not isinstance(data, dict) or env_id not in data:
        keys = ", ".join(map(str, data)) if isinstance(data, dict) else "none"
        raise ConfigError(f"--conf-file {str(p)!r} has no entry for env id {env_id!r} (it has: {keys})")
    entry = data[env_id]
    if not isinstance(entry, dict):
        raise ConfigError(f"--conf-file {str(p)!r}: the entry {env_id!r} must be a mapping of "
                          "hyperparameters")
    return dict(entry)


def _env_signature() -> set[str]:
    from impact_env.env.task import TASK_OPTIONS
    from impact_env.env.vector import ImpactCatchVectorEnv

    params = set(inspect.signature(ImpactCatchVectorEnv.__init__).parameters)
    return (params - {"self", "num_envs", "autoreset_mode", "render_mode", "task"}) | set(TASK_OPTIONS)


def resolve(algo: str, entry: dict, *, seed: int = 0, n_timesteps: int | None = None,
            n_envs: int | None = None,
            hp_overrides: dict | None = None, env_overrides: dict | None = None, scene: str | None = None,
            overrides: dict | None = None, conf_file: str | None = None,
            policy: str | None = None) -> RunConfig:
    """A :class:`RunConfig` from a YAML entry and the command line's overrides, every value checked."""
    algo = str(algo).lower()
    if algo not in ALGOS:
        raise ConfigError(f"algo = {algo!r}; expected one of {', '.join(ALGOS)}")
    entry = dict(entry)
    policy = policy if policy is not None else entry.pop("policy", "MlpPolicy")
    entry.pop("policy", None)
    if policy not in POLICIES[algo]:
        raise ConfigError(f"policy = {policy!r}: expected 'MlpPolicy' (the observation is a flat vector) or, "
                          f"for {algo}, {POLICIES[algo][1]!r} (the asymmetric actor-critic)")
    if entry.pop("normalize", False) not in (False, None):
        raise ConfigError("normalize: agents.train does not normalise (the observations are of order one and "
                          "model.zip must be the whole policy); remove the key or set it to false")
    n_envs = _int(1, 1_000_000)("n_envs", n_envs if n_envs is not None else entry.pop("n_envs", 16))
    entry.pop("n_envs", None)
    steps = n_timesteps if n_timesteps is not None else entry.pop("n_timesteps", None)
    entry.pop("n_timesteps", None)
    if steps is None:
        raise ConfigError("n_timesteps missing: give it in the YAML entry or --steps")
    steps = _int(1)("n_timesteps (--steps)", steps)
    seed = _int(0, 2**31 - 1)("seed", seed)

    env_kwargs = dict(entry.pop("env_kwargs", None) or {})
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"env_kwargs must be a mapping, got {env_kwargs!r}")
    if entry.pop("env_wrapper", None) is not None:
        raise ConfigError("env_wrapper: agents.train uses no env wrapper; give hold_ticks and residual "
                          "(the env's own options) in env_kwargs")
    action_limit = _action_limit(entry.pop("vec_env_wrapper", None))
    policy_kwargs = dict(entry.pop("policy_kwargs", None) or {})
    if not isinstance(policy_kwargs, dict):
        raise ConfigError("policy_kwargs must be a mapping (net_arch, log_std_init, ...), got "
                          f"{policy_kwargs!r}")
    env_kwargs.update(env_overrides or {})

    # hyperparameters: YAML, then --hp; policy kwargs may be given flat (--hp net_arch=[32, 32])
    hp = {}
    for key, value in list(entry.items()) + list((hp_overrides or {}).items()):
        if key in POLICY_SCHEMA or key == "net_arch":
            policy_kwargs[key] = value
        elif key in ZOO_KEYS:
            raise ConfigError(f"{key} cannot be overridden with --hp; use the matching option of "
                              "agents.train")
        else:
            hp[key] = value
    hp = {k: check_hyperparameter(algo, k, v) for k, v in hp.items()}
    policy_kwargs = {k: check_hyperparameter(algo, k, v) for k, v in policy_kwargs.items()}
    if algo == "ppo" and isinstance(policy_kwargs.get("net_arch"), list):
        arch = policy_kwargs["net_arch"]
        policy_kwargs["net_arch"] = {"pi": list(arch), "vf": list(arch)}  # separate actor and critic
    if algo == "ppo":
        n_steps = hp.get("n_steps", 2048)
        if n_steps * n_envs < 2:
            raise ConfigError(f"n_steps x n_envs = {n_steps * n_envs} must be > 1 (PPO's advantage "
                              "normalisation)")
        rollout, batch = n_steps * n_envs, hp.get("batch_size", 64)
        if batch > rollout:
            raise ConfigError(f"hyperparameter batch_size = {hp['batch_size']}: expected at most "
                              f"n_steps x n_envs = {rollout} (one rollout)")
        if rollout % batch:
            # SB3 would train on a truncated last mini-batch (and warn on every run)
            fits = [b for b in range(1, rollout + 1) if rollout % b == 0]
            near = sorted(fits, key=lambda b: abs(b - batch))[:2]
            raise ConfigError(f"hyperparameter batch_size = {batch}: must divide one rollout, n_steps x "
                              f"n_envs = {n_steps} x {n_envs} = {rollout}; e.g. batch_size = "
                              f"{' or '.join(map(str, sorted(near)))}")
    if policy_kwargs.get("squash_output") and not hp.get("use_sde"):
        raise ConfigError("squash_output = true needs use_sde = true (stable-baselines3)")

    # scene and env kwargs
    scene = scene if scene is not None else env_kwargs.pop("scene", "rig")
    env_kwargs.pop("scene", None)
    ov = dict(env_kwargs.pop("overrides", None) or {})
    ov.update(overrides or {})
    valid = _env_signature()
    for key in sorted(set(env_kwargs) & set(RETIRED_KEYS)):
        raise ConfigError(f"env_kwargs {key}: {RETIRED_KEYS[key]}")
    unknown = sorted(set(env_kwargs) - valid)
    if unknown:
        raise ConfigError(f"unknown env_kwargs {', '.join(map(repr, unknown))} for {ENV_ID}; valid: "
                          f"{', '.join(sorted(valid | {'scene', 'overrides'}))}")
    cfg = RunConfig(algo=algo, scene=str(scene), overrides=ov, env_kwargs=env_kwargs, hyperparameters=hp,
                    policy_kwargs=policy_kwargs, n_envs=n_envs, n_timesteps=steps, seed=seed,
                    conf_file=str(conf_file) if conf_file else None, policy=policy, action_limit=action_limit)
    check_env(cfg)
    return cfg


def _action_limit(wrapper) -> float | None:
    """The bound of RL Zoo's ``vec_env_wrapper: [{ActionLimit: {limit: L}}]``, the one vector-env
    wrapper agents.train builds (None: no wrapper)."""
    if wrapper is None:
        return None
    what = f"vec_env_wrapper: expected [{{{ACTION_LIMIT}: {{limit: L}}}}] with 0 < L <= 1"
    items = wrapper if isinstance(wrapper, list) else [wrapper]
    if len(items) != 1 or not isinstance(items[0], dict) or list(items[0]) != [ACTION_LIMIT]:
        raise ConfigError(f"{what}, got {wrapper!r}")
    kwargs = items[0][ACTION_LIMIT]
    if not isinstance(kwargs, dict) or set(kwargs) != {"limit"}:
        raise ConfigError(f"{what}, got {wrapper!r}")
    return _float(0.0, 1.0, lo_open=True)("vec_env_wrapper limit", kwargs["limit"])


def check_env(cfg: RunConfig) -> None:
    """Scene, overrides and env kwargs checked without building an env (no simulation, no
    compilation): the scene is loaded, the task's settings and the residual law built."""
    from impact_env.env.task import TaskConfig
    from impact_env.scene import load_scene

    scene = load_scene(cfg.scene, cfg.overrides or None)
    task_keys = set(inspect.signature(TaskConfig).parameters)
    try:
        task = TaskConfig(**{k: v for k, v in cfg.env_kwargs.items() if k in task_keys})
    except ValueError as exc:  # the env's own messages name the setting, its range and unit
        raise ConfigError(str(exc)) from None
    if task.residual is not None:
        from impact_env.policy.export import export_policy

        try:
            law = export_policy(task.residual, scene)
        except ValueError as exc:
            raise ConfigError(f"residual = {task.residual!r}: {exc}") from None
        if law.mlp is not None:
            raise ConfigError(f"residual = {task.residual!r} is a network; the residual's base must be a "
                              "classic law (e.g. 'pd-penetration')")
    from impact_env.control.observation import make_layout

    layout = make_layout(scene, cfg.observation, cfg.history)
    if cfg.policy in (ASYMMETRIC, ASYMMETRIC_SAC):
        if cfg.observation != "both":
            raise ConfigError(f"policy {cfg.policy} needs observation = 'both' (its critic reads the true "
                              "state)")
        sensors = make_layout(scene, "sensors", 1)
        want = {"frame_size": layout.frame_size, "actor_frame_size": sensors.frame_size,
                "history": cfg.history}
        # derived from the scene and the observation, so set here whatever the YAML says (it gives them
        # for RL Zoo, which does not derive them; --history or --scene may have changed them since)
        cfg.policy_kwargs.update(want)
    elif set(cfg.policy_kwargs) & {"frame_size", "actor_frame_size", "history"}:
        raise ConfigError("policy_kwargs frame_size, actor_frame_size, history belong to the asymmetric "
                          f"policies ({ASYMMETRIC}, {ASYMMETRIC_SAC}); policy is {cfg.policy!r}")
