"""Rewards and terminals of planned transitions: ``r(s, a, s')`` and ``P(terminal | s, a, s')``.

The planner diffuses windows ``τ = (s_0, a_0, …, s_H, a_H)`` without rewards (Section
2.2), so a transition ``(s_i, a_i, s_{i+1})`` cut from a generated window (EDIS's data
augmentation, Algorithm 1 line 14) has no reward and no terminal flag. EDIS diffuses
rewards and terminals as extra rows of its windows; here the planner is DUAL's and stays
as it is, and a small regression model fitted on the real transitions of
``D_offline ∪ D_online`` labels the generated ones. The recipe's env kits expose no
reward function (PointMaze's sparse reward depends on the goal in the observation, which
a learned model picks up as well).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from torch import nn

from torchrl_dual.diffusion.normalizer import Normalizer


class RewardModel(nn.Module):
    """An MLP from ``(s, a, s')`` to the reward and the logit of ``terminated``.

    Inputs are standardised by ``normalizer`` (states and actions; fitted on the offline
    data, saved with the model). Trained by :meth:`loss` on real transitions: squared
    error on the reward plus the logistic loss of the ``terminated`` flag.

    Args:
        normalizer (Normalizer): fitted state and action statistics (e.g. the planner's);
            copied.

    Keyword Args:
        hidden (int): MLP width. Defaults to ``128``.
        depth (int): hidden layers. Defaults to ``2``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import Normalizer
        >>> model = RewardModel(Normalizer(3, 2).fit(torch.randn(64, 3), torch.randn(64, 2)), hidden=16)
        >>> batch = TensorDict({"observation": torch.randn(6, 3), "action": torch.randn(6, 2),
        ...     "next": {"observation": torch.randn(6, 3), "reward": torch.randn(6, 1),
        ...              "terminated": torch.zeros(6, 1, dtype=torch.bool)}}, batch_size=[6])
        >>> loss, metrics = model.loss(batch)
        >>> loss.backward()
        >>> reward, terminated = model.predict(batch["observation"], batch["action"],
        ...                                    batch["next", "observation"])
        >>> reward.shape, terminated.dtype
        (torch.Size([6, 1]), torch.bool)
    """

    def __init__(self, normalizer: Normalizer, *, hidden: int = 128, depth: int = 2) -> None:
        super().__init__()
        obs_dim, action_dim = normalizer.obs_mean.shape[-1], normalizer.action_mean.shape[-1]
        self.normalizer = Normalizer(obs_dim, action_dim, eps=normalizer.eps)
        self.normalizer.load_state_dict(normalizer.state_dict())
        layers: list[nn.Module] = []
        width = 2 * obs_dim + action_dim
        for _ in range(depth):
            layers += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        self.net = nn.Sequential(*layers, nn.Linear(width, 2))

    def forward(
        self, observation: torch.Tensor, action: torch.Tensor, next_observation: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(reward, terminated logit)``, each ``[*B, 1]``."""
        norm = self.normalizer
        inputs = torch.cat(
            [
                norm.normalize_observation(observation),
                norm.normalize_action(action),
                norm.normalize_observation(next_observation),
            ],
            dim=-1,
        )
        out = self.net(inputs)
        return out[..., :1], out[..., 1:]

    @torch.no_grad()
    def predict(
        self, observation: torch.Tensor, action: torch.Tensor, next_observation: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(reward, terminated)``: the regressed reward and the flag ``P > 1/2``."""
        reward, logit = self(observation, action, next_observation)
        return reward, logit > 0

    def loss(self, batch: TensorDictBase) -> tuple[torch.Tensor, dict[str, float]]:
        """Squared reward error plus the ``terminated`` logistic loss on ``batch``."""
        reward, logit = self(batch["observation"], batch["action"], batch["next", "observation"])
        target = batch["next", "reward"].to(reward.dtype).reshape(reward.shape)
        terminated = batch["next", "terminated"].to(logit.dtype).reshape(logit.shape)
        reward_loss = F.mse_loss(reward, target)
        terminal_loss = F.binary_cross_entropy_with_logits(logit, terminated)
        return reward_loss + terminal_loss, {
            "reward_loss": reward_loss.item(),
            "terminal_loss": terminal_loss.item(),
        }
