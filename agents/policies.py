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
