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


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """ActorCriticPolicy (one shared flatten extractor) with an :class:`AsymmetricMlpExtractor`."""

    def __init__(self, *args, frame_size: int, actor_frame_size: int, history: int = 1, **kwargs):
        self._asym = (int(frame_size), int(actor_frame_size), int(history))
        self._indices = actor_indices(*self._asym)
        super().__init__(*args, **kwargs)
        if self.observation_space.shape[0] <= max(self._indices):
            raise ValueError(f"observation of {self.observation_space.shape[0]} entries is too small for "
                             f"frame_size {frame_size} x history {history}")

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = AsymmetricMlpExtractor(self.features_dim, self._indices, self.net_arch,
                                                    self.activation_fn, self.device)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.update(frame_size=self._asym[0], actor_frame_size=self._asym[1], history=self._asym[2])
        return data


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
