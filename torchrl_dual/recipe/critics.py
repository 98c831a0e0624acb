"""The recipe's critics ``Q_φ`` and ``V`` (Alg. 1 lines 7 and 15): a table by ``critic.name``.

Only TorchRL's IQL critics today (``critic/iql.yaml``); Cal-QL joins as a second entry
of :data:`CRITICS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import IQLLoss, SoftUpdate
from torchrl.objectives.value import TD0Estimator
from torchrl.objectives.value.functional import td0_return_estimate

from torchrl_dual.objectives.weighted_map_actor import _stackable_mlp, stacked_mlp_forward
from torchrl_dual.recipe.rules import Integer, Real, Text, key


@dataclass
class IQLCriticSettings:
    """``critic/iql.yaml``: TorchRL ``IQLLoss`` expectile value network and twin Q networks."""

    name: str = key(Text(), "the CRITICS entry")
    hidden: int = key(Integer(1), "MLP width of V and Q")
    depth: int = key(Integer(1), "hidden layers of V and Q")
    lr: float = key(Real(0, low_open=True), "Adam learning rate of V and Q")
    expectile: float = key(Real(0, 1, low_open=True, high_open=True), "IQL expectile τ")
    discount: float = key(Real(0, 1, low_open=True), "γ")
    target_update_tau: float = key(Real(0, 1, low_open=True), "soft target update rate")


@dataclass
class Critic:
    """TorchRL's IQL critics and what updates them.

    :meth:`losses` returns ``(loss.qvalue_loss(batch)[0], loss.value_loss(batch)[0])``;
    with ``fast_path`` (default) and plain-MLP critics it computes the same values and
    gradients (to float rounding) without TensorDict plumbing: the twin Q networks run
    as one batched matmul per layer, V directly on its weights.
    """

    loss: IQLLoss
    optimizer: torch.optim.Optimizer
    target_updater: SoftUpdate
    fast_path: bool = True

    def losses(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """IQL's Q loss (TD(0) target from ``V(s')``) and expectile V loss, both reduced."""
        if self.fast_path:
            out = _iql_losses_fast(self.loss, batch)
            if out is not None:
                return out
        return self.loss.qvalue_loss(batch)[0], self.loss.value_loss(batch)[0]


def _iql_losses_fast(loss: IQLLoss, batch: TensorDictBase):
    """:meth:`Critic.losses` for the recipe's configuration (plain-MLP critics, TD(0)
    without reward standardisation, l2 Q loss, mean reduction without loss masks, default
    keys), or ``None``
    when any of that does not hold."""
    estimator = loss.value_estimator
    keys, est_keys = loss.tensor_keys, getattr(estimator, "tensor_keys", None)
    q_mlp, v_mlp = _stackable_mlp(loss.qvalue_network), _stackable_mlp(loss.value_network)
    if (
        q_mlp is None
        or v_mlp is None
        or type(estimator) is not TD0Estimator
        or estimator.average_rewards
        or loss.loss_function != "l2"
        or loss.reduction != "mean"
        or list(loss.value_network.in_keys) != ["observation"]
        or list(loss.qvalue_network.in_keys) != ["observation", "action"]
        or (keys.state_action_value, keys.value) != ("state_action_value", "state_value")
        or (est_keys.reward, est_keys.done, est_keys.terminated) != ("reward", "done", "terminated")
        or batch.get(est_keys.steps_to_next_obs, None) is not None
        or batch.batch_dims != 1
        or any(batch.get(k, None) is not None for k in loss._loss_mask_keys())
    ):
        return None
    observation, action = batch.get("observation"), batch.get("action")
    next_observation = batch.get(("next", "observation"))
    reward = batch.get(("next", "reward"))
    done = batch.get(("next", "done"))
    terminated = batch.get(("next", "terminated"), done)
    state_action = torch.cat([observation, action], -1)
    value_params = loss.value_network_params
    # qvalue_loss: TD(0) target with V's (detached) weights at s', twin Q at (s, a)
    with torch.no_grad():
        next_value = stacked_mlp_forward(*v_mlp, value_params, next_observation, detach=True)
    gamma = estimator.gamma.to(reward.device)
    target = td0_return_estimate(
        gamma=gamma, next_state_value=next_value, reward=reward, terminated=terminated
    ).squeeze(-1)
    pred = stacked_mlp_forward(*q_mlp, loss.qvalue_network_params, state_action).squeeze(-1)
    q_loss = torch.nn.functional.mse_loss(pred, target.expand_as(pred), reduction="none")
    q_loss = q_loss.sum(0).mean()
    # value_loss: expectile regression of V(s) on min_k Q_target_k(s, a)
    target_q = stacked_mlp_forward(
        *q_mlp, loss.target_qvalue_network_params, state_action, detach=True
    )
    min_q = target_q.min(0)[0].squeeze(-1)
    value = stacked_mlp_forward(*v_mlp, value_params, observation).squeeze(-1)
    v_loss = loss.loss_value_diff(min_q - value, loss.expectile).mean()
    return q_loss, v_loss


class _NoActor(nn.Module):
    """The actor slot of TorchRL 0.14.1's ``IQLLoss``, which cannot be left empty.

    ``IQLLoss.__init__`` converts its ``actor_network`` to functional parameters and
    ``qvalue_loss`` reads ``actor_network.in_keys`` for the observation keys, so an actor
    is required even though the recipe only calls ``qvalue_loss`` and ``value_loss``:
    DUAL's actor loss is :class:`~torchrl_dual.WeightedMAPActorLoss` (Eq. 7). This one
    has no parameters, so the loss's state_dict holds no copy of the actor's weights.
    """

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raise RuntimeError(
            "IQLLoss.actor_loss is not DUAL's actor loss; use WeightedMAPActorLoss (Eq. 7)."
        )


def make_iql_critic(
    cfg: DictConfig,
    obs_dim: int,
    action_dim: int,
    actor: ProbabilisticActor | None = None,
    temperature: float = 1.0,
) -> Critic:
    """IQL's expectile value network V and twin Q networks (TorchRL ``IQLLoss``).

    Built in a fixed order (Q MLP, V MLP, then ``IQLLoss``, which redraws the second Q
    network's weights) so a seed gives the same critics. Without ``actor`` the loss's
    actor slot is a parameterless stand-in (DUAL trains its actor with its own loss);
    with one (the ``iql`` baseline), ``loss.actor_loss`` is IQL's advantage-weighted
    regression at ``temperature`` and ``loss`` holds the actor's weights, which the
    critic's optimizer leaves alone.
    """
    c = cfg.critic
    cells = [c.hidden] * c.depth

    class _QNet(nn.Module):
        concat_inputs = True  # mlp(cat(in_keys)): WeightedMAPActorLoss's batched path

        def __init__(self) -> None:
            super().__init__()
            self.mlp = MLP(
                in_features=obs_dim + action_dim,
                out_features=1,
                num_cells=cells,
                activation_class=nn.ReLU,
            )

        def forward(self, observation, action):
            return self.mlp(torch.cat([observation, action], -1))

    qvalue = ValueOperator(_QNet(), in_keys=["observation", "action"])
    value = ValueOperator(
        MLP(in_features=obs_dim, out_features=1, num_cells=cells, activation_class=nn.ReLU),
        in_keys=["observation"],
    )
    if actor is None:
        actor = ProbabilisticActor(
            TensorDictModule(_NoActor(), in_keys=["observation"], out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"],
            distribution_class=torch.distributions.Normal,
        )
    loss = IQLLoss(
        actor,
        qvalue,
        value,
        expectile=c.expectile,
        temperature=temperature,
        num_qvalue_nets=2,
        loss_function="l2",
    ).to(cfg.device)
    loss.make_value_estimator(gamma=c.discount)
    params = list(loss.qvalue_network_params.values(True, True)) + list(
        loss.value_network_params.values(True, True)
    )
    optimizer = torch.optim.Adam(params, lr=c.lr)
    return Critic(loss, optimizer, SoftUpdate(loss, tau=c.target_update_tau))


CRITICS: dict[str, tuple[type, Callable[..., Critic]]] = {
    "iql": (IQLCriticSettings, make_iql_critic),
}
"""``critic.name`` -> (schema of ``critic.*``, ``(cfg, obs_dim, action_dim, actor=None,
temperature=1.0) -> Critic``)."""
