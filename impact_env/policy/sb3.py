"""Saved stable-baselines3 models as policies, so trained agents join the same comparison.

Spec: ``PATH.zip``, ``ALGO:PATH.zip`` (``ppo``, ``sac``, ``td3``, ``a2c``, ``ddpg``), optionally
followed by ``:observation=sensors,history=4,hold_ticks=4,residual=pd-penetration`` (or
``,observation=...``).  Without an algorithm each one is tried in turn.

A model acts as it was trained only with the env settings it was trained with: the
observation, its history, ``hold_ticks`` and the ``residual`` law its actions are added to.
They come from the settings file next to the model (``PATH.json``, which ``agents.train``
writes beside every model it saves: ``model``, ``best_model``, each checkpoint, an interrupted
run's), the spec overriding it key by key.  Nothing is guessed: without the file, the spec
must give all four (``residual=none`` for none), and a model whose observation space does not
have the size those settings give is refused.

A model whose settings file says ``"estimator": "ekf"`` reads the scene's extended Kalman filter's
estimate after its observation row (``agents.distill --student-observation estimate``): the filter
has memory and is told every command, which SB3's ``predict`` has no place for, so such a model
is loaded as its compiled policy (:func:`impact_env.policy.export.export_sb3`), the filter inside.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError
from impact_env.control.observation import OBSERVATIONS, make_layout
from impact_env.control.policy import CompiledPolicy
from impact_env.scene import load_scene

ALGOS = ("ppo", "sac", "td3", "a2c", "ddpg")
# the env settings a model's actions mean something only with (its settings file, or the spec)
SETTINGS = ("observation", "history", "hold_ticks", "residual")


def parse_model_spec(spec: str) -> tuple[str | None, Path, dict]:
    """``"ppo:runs/a.zip:observation=sensors"`` -> ("ppo", Path("runs/a.zip"), {"observation": "sensors"})."""
    head, sep, tail = spec.partition(".zip")
    if not sep:
        raise ConfigError(f"model spec {spec!r} must name a .zip file saved by stable-baselines3")
    algo = None
    path = head + ".zip"
    pre, colon, rest = head.partition(":")
    if colon and pre.lower() in ALGOS:
        algo, path = pre.lower(), rest + ".zip"
    opts: dict = {}
    for item in filter(None, (s.strip() for s in tail.lstrip(":,").replace(":", ",").split(","))):
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in SETTINGS:
            raise ConfigError(f"model spec {spec!r}: option {item!r} must be one of "
                              f"{', '.join(k + '=...' for k in SETTINGS)}")
        opts[key.strip()] = value.strip()
    for key in ("history", "hold_ticks"):
        if key in opts:
            try:
                opts[key] = int(opts[key])
            except ValueError:
                raise ConfigError(f"model spec {spec!r}: {key} must be an integer, "
                                  f"got {opts[key]!r}") from None
    if "residual" in opts and opts["residual"].lower() == "none":
        opts["residual"] = None
    if "observation" in opts and opts["observation"] not in OBSERVATIONS:
        raise ConfigError(f"model spec {spec!r}: observation must be one of {', '.join(OBSERVATIONS)}")
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"model file {str(p)!r} not found (policy spec {spec!r})")
    return algo, p, opts


class ModelPolicy:
    """A loaded SB3 model with the attributes the comparison needs: ``observation``, ``history``,
    ``hold_ticks`` (control periods per action) and ``residual`` (the spec of the classic law its
    actions add to, or None), the last two from the env kwargs in its ``model.json``."""

    def __init__(self, model, observation: str, history: int, name: str, hold_ticks: int = 1,
                 residual: str | None = None, estimator: bool = False):
        self.model = model
        self.estimator = bool(estimator)
        self.observation = observation
        self.history = history
        self.name = name
        self.hold_ticks = int(hold_ticks)
        self.residual = residual

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)


SB3_HINT = ("stable-baselines3 and torch, which are not installed: they are the optional extra 'sb3' "
            "(pip install 'impact-env[sb3]'; on a machine without a GPU install torch's CPU build "
            "first, README)")


def require_sb3():
    """The stable_baselines3 module, or ConfigError with the install hint."""
    try:
        import stable_baselines3
    except ImportError:
        raise ConfigError(f"a saved stable-baselines3 model needs {SB3_HINT}") from None
    return stable_baselines3


def _load(algo: str | None, path: Path):
    sb3 = require_sb3()

    names = [algo] if algo else list(ALGOS)
    errors = []
    for name in names:
        cls = getattr(sb3, name.upper())
        try:
            return cls.load(str(path), device="cpu")
        except Exception as exc:  # wrong algorithm for this file: try the next one
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    raise ConfigError(f"could not load {str(path)!r} as a stable-baselines3 model ({'; '.join(errors)})")


def model_settings(path: Path, opts: dict, spec: str) -> dict:
    """The model's env settings (:data:`SETTINGS`): its settings file, overridden by the spec's
    keys; ConfigError naming the file and the keys when neither gives all of them."""
    sidecar = path.with_suffix(".json")
    settings: dict = {}
    if sidecar.is_file():
        try:
            meta = json.loads(sidecar.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"the settings file {str(sidecar)!r} of model {str(path)!r} is not JSON: "
                              f"{exc}") from None
        env_kwargs = meta.get("env_kwargs") or {}
        settings = {"observation": meta.get("observation", "sensors"), "history": int(meta.get("history", 1)),
                    "hold_ticks": int(meta.get("hold_ticks", env_kwargs.get("hold_ticks", 1))),
                    "residual": meta.get("residual", env_kwargs.get("residual")),
                    "estimator": meta.get("estimator")}
    settings.update(opts)
    missing = [k for k in SETTINGS if k not in settings]
    if missing:
        example = ",".join(f"{k}={v}" for k, v in zip(SETTINGS, ("sensors", "1", "1", "none"), strict=True))
        raise ConfigError(
            f"model {str(path)!r} has no settings file {str(sidecar)!r} (agents.train writes one beside "
            f"every model it saves), so the env settings it was trained with are unknown and would be "
            f"guessed; give {', '.join(missing)} in the spec, e.g. "
            f"{spec.split('.zip')[0]}.zip:{example} (residual=none for none), with the values it was "
            "trained with")
    if settings["observation"] not in OBSERVATIONS:
        raise ConfigError(f"model {str(path)!r}: observation {settings['observation']!r} is not one of "
                          f"{', '.join(OBSERVATIONS)}")
    return settings


def load_model_policy(spec: str, scene) -> ModelPolicy | CompiledPolicy:
    """The model of ``spec`` with its env settings (see the module doc)."""
    scene = load_scene(scene)
    algo, path, opts = parse_model_spec(spec)
    st = model_settings(path, opts, spec)
    model = _load(algo, path)
    estimator = st.get("estimator")
    if estimator not in (None, "ekf"):
        raise ConfigError(f"model {str(path)!r}: estimator {estimator!r} in its settings file is not 'ekf' or "
                          "absent")
    size = int(model.observation_space.shape[0])
    want = _size(scene, st["observation"], st["history"])
    extra = ""
    if estimator and want is not None:
        from impact_env.control.estimation.features import N_FEATURES

        want += N_FEATURES
        extra = f" and the filter's {N_FEATURES} estimates"
    if want != size:
        raise ConfigError(f"model {str(path)!r} takes {size} observation entries, but observation "
                          f"{st['observation']!r} with history {st['history']} on scene {scene.name!r}{extra} "
                          f"gives {want}: the settings are not the ones it was trained with")
    policy = ModelPolicy(model, st["observation"], st["history"], spec, hold_ticks=int(st["hold_ticks"]),
                         residual=st["residual"], estimator=bool(estimator))
    if estimator:
        return compiled_behind_filter(policy, scene, spec)
    return policy


def compiled_behind_filter(policy: ModelPolicy, scene, spec: str) -> CompiledPolicy:
    """A model trained behind the scene's filter as its compiled policy, the filter inside
    (as :func:`impact_env.policy.export.export_sb3` exports any model; such a model has no
    residual law and acts every control period)."""
    model = policy.model
    space = model.action_space
    if space.shape != (1,):
        raise ConfigError(f"the model's action space {space} is not the shaker's one command")
    layers, output = sb3_layers(model)
    return CompiledPolicy.from_mlp(path_stem(spec), layers, output, float(space.low[0]), float(space.high[0]),
                                   scene, policy.observation, policy.history, hold_ticks=policy.hold_ticks,
                                   source={"spec": spec, "algo": type(model).__name__.lower()}, estimator=True)


def path_stem(spec: str) -> str:
    """The name a compiled model takes: its file's stem."""
    return Path(spec.split(":")[-1]).stem if spec else "mlp"


def sb3_layers(model) -> tuple[list[dict], str]:
    """(layers, output transform) of an SB3 model's deterministic actor."""
    import torch.nn as nn

    pol = model.policy
    if hasattr(pol, "mlp_extractor") and hasattr(pol, "action_net"):  # PPO, A2C
        if type(pol.features_extractor).__name__ != "FlattenExtractor":
            raise ConfigError("only the default FlattenExtractor can be exported")
        modules = list(pol.mlp_extractor.policy_net) + [pol.action_net]
        output = "squash" if pol.squash_output else "clip"
    elif hasattr(pol, "actor") and hasattr(pol.actor, "latent_pi"):  # SAC
        modules = list(pol.actor.latent_pi) + _flat(pol.actor.mu)
        output = "squash"
    elif hasattr(pol, "actor") and hasattr(pol.actor, "mu"):  # TD3, DDPG: mu ends in a Tanh
        modules = _flat(pol.actor.mu)
        if not isinstance(modules[-1], nn.Tanh):
            raise ConfigError("the TD3/DDPG actor should end in a Tanh")
        modules = modules[:-1]
        output = "squash"  # that tanh, then unscaled
    else:
        raise ConfigError(f"cannot read the actor of {type(model).__name__}'s policy {type(pol).__name__}")
    layers: list[dict] = []
    for m in modules:
        if isinstance(m, nn.Linear):
            layers.append({"weight": m.weight.detach().cpu().double().numpy(),
                           "bias": (m.bias.detach().cpu().double().numpy() if m.bias is not None
                                    else np.zeros(m.out_features)),
                           "activation": "identity", "params": [0.0, 0.0]})
            continue
        if not layers:
            raise ConfigError(f"the actor starts with {type(m).__name__}, not a Linear layer")
        act, params = _activation(m)
        if layers[-1]["activation"] != "identity":
            raise ConfigError(f"two activations in a row in the actor ({type(m).__name__})")
        layers[-1]["activation"], layers[-1]["params"] = act, params
    return layers, output


def _flat(module):
    import torch.nn as nn

    return list(module) if isinstance(module, nn.Sequential) else [module]


def _activation(m) -> tuple[str, list[float]]:
    import torch.nn as nn

    if isinstance(m, nn.Tanh):
        return "tanh", [0.0, 0.0]
    if isinstance(m, nn.ReLU):
        return "relu", [0.0, 0.0]
    if isinstance(m, nn.Hardtanh):
        return "hardtanh", [float(m.min_val), float(m.max_val)]
    if isinstance(m, nn.LeakyReLU):
        return "leaky_relu", [float(m.negative_slope), 0.0]
    if isinstance(m, nn.ELU):
        return "elu", [float(m.alpha), 0.0]
    if isinstance(m, nn.Identity):
        return "identity", [0.0, 0.0]
    raise ConfigError(f"activation {type(m).__name__} cannot be exported (supported: Tanh, ReLU, Hardtanh, "
                      "LeakyReLU, ELU)")



def _size(scene, observation, history) -> int | None:
    try:
        return make_layout(scene, observation, history).size
    except ConfigError:
        return None
