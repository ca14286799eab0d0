"""An asymmetric actor-critic for PPO: the actor reads the sensor entries of the observation, the
critic reads everything, including the true state (``observation="both"``).

Why: the sensors show the policy's own command at once (the accelerometer and the force
transducer on body 2 respond to the shaker within the tick), so a critic on the sensor frame
values what the command *looks like* as well as what it does; a critic on the true state
``x1, v1, x2, v2`` has no such shortcut.  In the experiments (docs/agents.md, e6) it raised the
critic's explained variance from 0.2-0.4 to 0.8 but did not by itself stop PPO's drift away from
the residual's starting law; Monte-Carlo advantages did.  The actor never reads the privileged entries, so the
deployed policy is a sensor-fed controller: its action does not change when they change (tested).

Use ``observation="both"`` and ``policy: agents.policies.AsymmetricActorCriticPolicy`` with
``policy_kwargs: {frame_size: F, actor_frame_size: S, history: H}`` (``agents.train`` fills them
in from the scene's layout): F entries per frame of which the first S are the sensors, H frames,
then H past commands when H > 1; the actor reads the S sensor entries of every frame and the
past commands.
"""

from __future__ import annotations

import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor
from stable_baselines3.common.utils import get_device
from stable_baselines3.sac.policies import SACPolicy
from torch import nn


def actor_indices(frame_size: int, actor_frame_size: int, history: int) -> list[int]:
    """Positions the actor reads in an observation of ``history`` frames of ``frame_size``."""
    if not 1 <= actor_frame_size <= frame_size or history < 1:
        raise ValueError(f"actor_frame_size = {actor_frame_size} must be in [1, frame_size = {frame_size}] "
                         f"and history = {history} >= 1")
    idx = [h * frame_size + j for h in range(history) for j in range(actor_frame_size)]
    if history > 1:
        idx += [history * frame_size + h for h in range(history)]
    return idx


class AsymmetricMlpExtractor(MlpExtractor):
    """SB3's MlpExtractor whose policy network reads only ``indices`` of the features."""

    def __init__(self, feature_dim: int, indices: list[int], net_arch, activation_fn, device="auto"):
        super().__init__(feature_dim, net_arch, activation_fn, device)
        pi = net_arch["pi"] if isinstance(net_arch, dict) else net_arch
        layers: list[nn.Module] = []
        last = len(indices)
        for width in pi:
            layers += [nn.Linear(last, width), activation_fn()]
            last = width
        self.policy_net = nn.Sequential(*layers).to(get_device(device))
        self.register_buffer("actor_idx", th.as_tensor(indices, dtype=th.long))

    def forward(self, features: th.Tensor):
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return self.policy_net(features.index_select(1, self.actor_idx))


class SensorActor:
    """What the asymmetric policies share: the actor's entries of the observation (``_indices``,
    from ``frame_size``, ``actor_frame_size`` and ``history``: :func:`actor_indices`), checked
    against the observation space, and kept among the constructor's parameters (a saved model
    loads with them)."""

    def __init__(self, *args, frame_size: int, actor_frame_size: int, history: int = 1, **kwargs):
        self._asym = (int(frame_size), int(actor_frame_size), int(history))
        self._indices = actor_indices(*self._asym)
        super().__init__(*args, **kwargs)
        if self.observation_space.shape[0] <= max(self._indices):
            raise ValueError(f"observation of {self.observation_space.shape[0]} entries is too small for "
                             f"frame_size {frame_size} x history {history}")

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.update(frame_size=self._asym[0], actor_frame_size=self._asym[1], history=self._asym[2])
        return data


class AsymmetricActorCriticPolicy(SensorActor, ActorCriticPolicy):
    """ActorCriticPolicy (one shared flatten extractor) with an :class:`AsymmetricMlpExtractor`."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = AsymmetricMlpExtractor(self.features_dim, self._indices, self.net_arch,
                                                    self.activation_fn, self.device)


class IndexSelect(nn.Module):
    """A features extractor that keeps ``indices`` of a flat observation (the actor's entries)."""

    def __init__(self, observation_space, indices: list[int]):
        super().__init__()
        self._observation_space = observation_space
        self.features_dim = len(indices)
        self.register_buffer("actor_idx", th.as_tensor(indices, dtype=th.long))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return th.flatten(observations, start_dim=1).float().index_select(1, self.actor_idx)


class AsymmetricSACPolicy(SensorActor, SACPolicy):
    """SAC's policy with an actor that reads the sensor entries only (``IndexSelect``) and critics
    that read everything, the true state included (``observation="both"``): the asymmetric
    actor-critic of :class:`AsymmetricActorCriticPolicy` for SAC.

    Why for SAC: its critic learns Q(o, a) by bootstrapping, and the sensor frame does not say
    where body 1 is before the touch, nor how fast it comes: the same observation stands for
    drops with very different futures, and the TD targets average them.  The true state removes
    that aliasing from the critic, while the actor, the part that is deployed, stays a sensor
    controller.  :func:`sensor_actor_model` turns a trained model into the plain sensor model
    that is shipped, exported and compiled."""

    def make_actor(self, features_extractor=None):
        from stable_baselines3.sac.policies import Actor

        fe = IndexSelect(self.observation_space, self._indices)
        actor_kwargs = self._update_features_extractor(self.actor_kwargs, fe)
        return Actor(**actor_kwargs).to(self.device)


def init_sac_actor(model, log_std_init: float, mean_gain: float = 0.01) -> None:
    """Start an SB3 SAC actor as PPO's starts: the mean head orthogonal with gain ``mean_gain``
    and bias 0 (the action starts near 0: on a residual env, the classic law itself), and, without
    gSDE, the log-std head's weights 0 and bias ``log_std_init`` (std ``exp(log_std_init)`` in every
    state).

    Why: SB3's SAC reads ``log_std_init`` only with gSDE; without it both heads keep PyTorch's
    default init, a log-std near 0 (std about 1 before the tanh: about +-200 N of exploration on
    top of the law from the first step), which the experiments of docs/agents.md found ruinous on
    the residual.  The heads stay ordinary Linear layers, so the saved model is a plain SAC
    ``MlpPolicy`` (loads, exports and runs compiled as before).  Parameters are changed in place:
    the optimisers already hold them."""
    import math

    if not math.isfinite(log_std_init):
        raise ValueError(f"log_std_init = {log_std_init!r} must be a finite number")
    actor = model.policy.actor
    with th.no_grad():
        nn.init.orthogonal_(actor.mu.weight, gain=mean_gain)
        actor.mu.bias.zero_()
        if isinstance(actor.log_std, nn.Linear):  # without gSDE; with it, SB3 applies log_std_init itself
            actor.log_std.weight.zero_()
            actor.log_std.bias.fill_(float(log_std_init))


def is_asymmetric(model) -> bool:
    """Whether an SB3 model's actor reads a part of the observation only (the asymmetric
    policies of this module)."""
    return isinstance(model.policy, (AsymmetricActorCriticPolicy, AsymmetricSACPolicy))


def sensor_actor_model(src, dst, settings: dict | None = None):
    """The deployable sensor controller of an asymmetric model: a plain SB3 ``MlpPolicy`` model
    of the same algorithm over the sensor observation (``observation="sensors"``, the same history)
    whose actor holds the trained actor's weights, saved to ``dst`` (``.zip``) with its settings
    file beside it (``dst`` with ``.json``: the source's settings with the observation changed and
    ``converted_from``).  Returns ``dst``.

    The actor of :class:`AsymmetricActorCriticPolicy` / :class:`AsymmetricSACPolicy` reads the
    sensor entries of each frame and the past commands, in the order the sensor observation
    holds them, so with the same weights it acts on the sensor observation exactly as it acted on
    ``observation="both"`` (tested).  The critic is not carried over (the trained one read the
    true state, which a deployed controller has not): the file is for acting (``compare``, the
    export, the rig), not for training on.  ``settings`` default to ``src``'s settings file."""
    import json
    from pathlib import Path

    import gymnasium
    from stable_baselines3 import PPO, SAC

    src, dst = Path(src), Path(dst)
    meta = dict(settings) if settings is not None else json.loads(src.with_suffix(".json").read_text())
    algo = meta["algo"]
    cls = PPO if algo == "ppo" else SAC
    model = cls.load(str(src), device="cpu")
    if not is_asymmetric(model):
        raise ValueError(f"{src} is not an asymmetric model (its policy is {type(model.policy).__name__})")
    idx = model.policy._indices
    low, high = model.observation_space.low[idx], model.observation_space.high[idx]
    obs_space = gymnasium.spaces.Box(low, high, dtype=model.observation_space.dtype)
    kwargs = {k: v for k, v in model.policy_kwargs.items()
              if k not in ("frame_size", "actor_frame_size", "history")}
    # built as SB3's load builds a model: without an env, from its spaces
    plain = cls("MlpPolicy", None, policy_kwargs=kwargs, device="cpu", _init_setup_model=False,
                **({"n_steps": model.n_steps, "batch_size": model.batch_size} if algo == "ppo" else
                   {"buffer_size": 1, "target_entropy": float(model.target_entropy)}))
    plain.observation_space, plain.action_space, plain.n_envs = obs_space, model.action_space, 1
    plain._setup_model()
    with th.no_grad():
        if algo == "ppo":
            plain.policy.mlp_extractor.policy_net.load_state_dict(model.policy.mlp_extractor.policy_net.state_dict())
            plain.policy.action_net.load_state_dict(model.policy.action_net.state_dict())
            plain.policy.log_std.copy_(model.policy.log_std)
        else:
            a, b = plain.policy.actor, model.policy.actor
            for name in ("latent_pi", "mu", "log_std"):
                getattr(a, name).load_state_dict(getattr(b, name).state_dict())
    dst.parent.mkdir(parents=True, exist_ok=True)
    plain.save(dst)
    env_kwargs = dict(meta.get("env_kwargs") or {}, observation="sensors")
    out = {**meta, "observation": "sensors", "env_kwargs": env_kwargs, "policy": "MlpPolicy",
           "converted_from": {"model": str(src), "observation": meta.get("observation"),
                              "policy": meta.get("policy"),
                              "note": "the actor of an asymmetric actor-critic; the critic is not "
                                      "carried over (it read the true state)"}}
    dst.with_suffix(".json").write_text(json.dumps(out, indent=2, default=str) + "\n")
    return dst


def deployable(model_path, settings: dict | None = None):
    """The model file that acts as a trained model's controller: ``model_path`` itself, or, for an
    asymmetric actor-critic, the plain sensor model of its actor (:func:`sensor_actor_model`),
    written beside it as ``STEM.sensors.zip`` with its settings file.  ``settings`` default to the
    model's settings file (``PATH.json``, else ``model.json`` beside it)."""
    import json
    from pathlib import Path

    path = Path(model_path)
    if settings is None:
        for p in (path.with_suffix(".json"), path.parent / "model.json"):
            if p.is_file():
                settings = json.loads(p.read_text())
                break
    if not settings or settings.get("observation") != "both":  # only "both" feeds an asymmetric policy
        return path
    from stable_baselines3 import PPO, SAC

    model = (PPO if settings.get("algo") == "ppo" else SAC).load(str(path), device="cpu")
    if not is_asymmetric(model):
        return path
    return sensor_actor_model(path, path.with_name(path.stem + ".sensors.zip"), settings)
