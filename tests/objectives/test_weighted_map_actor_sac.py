"""Tests for the ``sac`` weighting of the weighted MAP actor loss (Eq. 7 with the critic's Q
and an entropy term): gradient paths, the critic ensemble's min, and the action box
(docs/equations.md, deviation 2a)."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded, Unbounded
from torchrl.modules import MLP, ValueOperator
from toy import linear_head_actor, mlp_by_hand, observation_action_batch, tiny_iql_loss

from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.objectives.weighted_map_actor import WeightedMAPActorLoss

OBS, ACT = 3, 2
BOX = Bounded(-1.0, 1.0, shape=(ACT,))


# ----------------------------------------------------------------------------- gradients
def test_sac_gradient_flows_to_the_actor_through_q_of_the_sampled_action():
    iql = tiny_iql_loss()
    actor = linear_head_actor()
    # α = 0: the only path from the loss to the head is Q(s, a ~ π).
    loss_fn = WeightedMAPActorLoss.from_iql(
        actor, iql, weighting="sac", entropy_coef=0.0, action_spec=BOX
    )
    loss_fn(observation_action_batch())["loss_actor"].backward()
    assert actor.head.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in iql.parameters())


def test_sac_without_explicit_critic_params_keeps_gradients_out_of_q():
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    loss_fn = WeightedMAPActorLoss(
        linear_head_actor(), qvalue_network=qvalue, weighting="sac", action_spec=BOX
    )
    loss_fn(observation_action_batch())["loss_actor"].backward()
    assert all(p.grad is None for p in qvalue.parameters())


def test_a_ten_member_ensemble_gives_the_min_by_hand_and_its_action_gradient():
    """SO2's critic: all members evaluated in one vmapped call; the value is the min of
    the members computed one by one, and so is its gradient with respect to the action
    (the path the ``sac`` weighting trains the actor through)."""
    members = 10
    nets = []
    for seed in range(members):
        torch.manual_seed(seed)
        nets.append(
            ValueOperator(
                MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
                in_keys=["observation", "action"],
            )
        )
    params = TensorDict.from_modules(*nets, as_module=True)
    loss_fn = WeightedMAPActorLoss(
        linear_head_actor(),
        qvalue_network=nets[0],
        qvalue_params=params,
        weighting="sac",
        action_spec=BOX,
    )
    batch = observation_action_batch(32)
    action = batch["action"].clone().requires_grad_(True)
    batch["action"] = action
    q = loss_fn.q_value(batch)
    (grad,) = torch.autograd.grad(q.sum(), action)

    by_hand_action = action.detach().clone().requires_grad_(True)
    sa = torch.cat([batch["observation"], by_hand_action], -1)
    expected = torch.stack([mlp_by_hand(params[k].data, sa) for k in range(members)]).min(0)
    (expected_grad,) = torch.autograd.grad(expected.values.sum(), by_hand_action)
    assert expected.indices.unique().numel() > 1  # the min switches member across the batch
    torch.testing.assert_close(q, expected.values)
    torch.testing.assert_close(grad, expected_grad)
    assert all(p.grad is None for p in params.values(True, True))  # the critic stays fixed


# ----------------------------------------------------------------------------- action box
class _SlopeQ(nn.Module):
    """``Q(s, a) = slope · Σ a``: rises without end along every action dimension, as a
    critic's extrapolation outside the box may."""

    def __init__(self, slope: float) -> None:
        super().__init__()
        self.slope = slope

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.slope * action.sum(-1, keepdim=True)


def _sac_on_slope(
    action_spec, bias: float, slope: float = 5.0, entropy_coef: float = 0.0
) -> tuple[WeightedMAPActorLoss, LinearHeadActor]:
    actor = linear_head_actor()
    with torch.no_grad():
        actor.head.weight.zero_()
        actor.head.bias.fill_(bias)  # μ(s) = bias in every state and dimension
    qvalue = ValueOperator(_SlopeQ(slope), in_keys=["observation", "action"])
    loss = WeightedMAPActorLoss(
        actor,
        qvalue_network=qvalue,
        weighting="sac",
        entropy_coef=entropy_coef,
        action_spec=action_spec,
    )
    return loss, actor


def test_sac_reads_q_at_the_clamped_action_so_an_actor_outside_the_box_gets_no_push():
    """The runaway ``algo=dual critic=so2`` had (its actor's mean at |μ| ≈ 3 and growing, a
    constant -6.0 score): Q queried outside the box rewards leaving it. With the box,
    the loss is ``-Q(s, clamp(a))``, exactly, and a mean beyond the box gets no
    gradient from Q; inside it, the same push as without a box."""
    batch = observation_action_batch(4096)
    torch.manual_seed(0)
    near_edge, actor = _sac_on_slope(BOX, bias=0.8)  # N(0.8, 0.3²): a quarter of the draws clamped
    out = near_edge(batch.clone(False))
    out["loss_actor"].backward()
    # by hand, per dimension, X ~ N(μ, σ²), z = (1 - μ) / σ (the lower face is 6σ away):
    # E[clamp(X, -1, 1)] = μ Φ(z) - σ φ(z) + (1 - Φ(z)), d/dμ = Φ(z) = P(X < 1)
    mu, std = 0.8, float(actor.std.detach()[0])
    z = (1.0 - mu) / std
    cdf, pdf = 0.5 * (1 + math.erf(z / math.sqrt(2))), math.exp(-z * z / 2) / math.sqrt(2 * math.pi)
    mean_clamped = mu * cdf - std * pdf + (1 - cdf)
    # Monte-Carlo tolerances ≈ 4 standard errors (4096 draws); without the box the loss
    # would be -8.0 and the gradient -5.0
    torch.testing.assert_close(
        out["loss_actor"], torch.tensor(-5.0 * ACT * mean_clamped), atol=0.1, rtol=0
    )
    torch.testing.assert_close(
        actor.head.bias.grad, torch.full((ACT,), -5.0 * cdf), atol=0.15, rtol=0
    )

    outside, actor = _sac_on_slope(BOX, bias=4.0)  # every draw of N(4, 0.3²) is clamped to 1
    out = outside(batch.clone(False))
    torch.testing.assert_close(out["loss_actor"], torch.tensor(-5.0 * ACT))
    out["loss_actor"].backward()
    assert actor.head.bias.grad.abs().max() == 0 and actor.head.weight.grad.abs().max() == 0

    unbounded, actor = _sac_on_slope(Unbounded(shape=(ACT,)), bias=4.0)  # opt-in: no box
    unbounded(batch.clone(False))["loss_actor"].backward()
    torch.testing.assert_close(actor.head.bias.grad, torch.full((ACT,), -5.0))


def test_sac_entropy_term_scores_the_clamped_draw_and_pulls_a_mean_back_into_the_box():
    """``α·log π`` of the executed (censored) Gaussian: on a flat critic, a mean past the
    face at 1 gets ``d/dμ E[α log π] = α φ(w) / σ`` per dimension, ``w = (μ - 1) / σ``
    (only the draws on the face depend on μ, through ``log P(X ≥ 1) = log Φ(w)``), so a
    gradient step moves it back in; the Gaussian score of the raw draw gives it 0."""
    alpha, mu = 0.2, 1.2
    loss, actor = _sac_on_slope(BOX, bias=mu, slope=0.0, entropy_coef=alpha)
    torch.manual_seed(0)
    loss(observation_action_batch(4096))["loss_actor"].backward()
    std = float(actor.std.detach()[0])
    w = (mu - 1.0) / std
    expected = alpha * math.exp(-w * w / 2) / math.sqrt(2 * math.pi) / std
    torch.testing.assert_close(
        actor.head.bias.grad, torch.full((ACT,), expected), atol=0.02, rtol=0
    )
    assert expected > 0.2  # inward, and far outside the tolerance


def test_the_action_box_follows_the_loss_to_its_device_and_dtype():
    loss, _ = _sac_on_slope(BOX, bias=0.0)
    loss.double()  # as .to(device): the bounds are a submodule's buffers
    assert loss.action_box.low.dtype == loss.action_box.high.dtype == torch.float64


# ----------------------------------------------------------------------------- Cal-QL critic
def test_from_iql_on_a_calql_loss_without_v_builds_the_sac_loss_on_its_target_twin_q():
    """A Cal-QL critic loss has no V: ``from_iql`` builds the ``sac`` loss on its target
    twin Q, ``Q(s, a) = min_k Q_k(s, a)`` by hand, and leaves the value key alone."""
    from toy import tanh_normal_actor

    from torchrl_dual.objectives import CalQLLoss

    torch.manual_seed(0)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    calql = CalQLLoss(tanh_normal_actor(OBS, ACT, BOX), qvalue, num_random=4)
    assert not hasattr(calql, "value_network")
    loss_fn = WeightedMAPActorLoss.from_iql(
        linear_head_actor(), calql, weighting="sac", action_spec=BOX
    )
    assert loss_fn.tensor_keys.value == "state_value"
    batch = observation_action_batch(8)
    sa = torch.cat([batch["observation"], batch["action"]], -1)
    target = calql.target_qvalue_network_params
    expected = torch.stack([mlp_by_hand(target[k], sa) for k in range(2)]).min(0).values
    torch.testing.assert_close(loss_fn.q_value(batch), expected.detach())
    loss_fn(batch)["loss_actor"].backward()
