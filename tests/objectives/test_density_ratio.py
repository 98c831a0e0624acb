"""Tests for OFF2ON's density-ratio loss (the Jensen-Shannon variational estimator)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from torchrl_dual.objectives.density_ratio import DensityRatioLoss, make_density_ratio_network

OBS, ACT = 3, 2


class _Constant(nn.Module):
    """A fake ratio network ``w(s, a) = c``."""

    def __init__(self, c: float) -> None:
        super().__init__()
        self.c = nn.Parameter(torch.tensor(c))

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.c.expand(*observation.shape[:-1], 1)


def _constant_loss(c: float) -> DensityRatioLoss:
    net = TensorDictModule(
        _Constant(c), in_keys=["observation", "action"], out_keys=["density_ratio"]
    )
    return DensityRatioLoss(net)


def _gaussian_batch(n: int, shift: torch.Tensor, *, gen: torch.Generator) -> TensorDict:
    """``n`` offline ``(s, a) ∼ N(0, I)`` then ``n`` online ``(s, a) ∼ N(shift, I)``."""
    x = torch.randn(2 * n, OBS + ACT, generator=gen)
    x[n:] += shift
    online = torch.arange(2 * n) >= n
    return TensorDict(observation=x[:, :OBS], action=x[:, OBS:], online=online, batch_size=[2 * n])


def test_loss_matches_the_closed_form_and_its_minimiser_is_the_true_ratio():
    gen = torch.Generator().manual_seed(0)
    batch = _gaussian_batch(8, torch.zeros(OBS + ACT), gen=gen)  # same distribution: w* = 1
    for c in (0.5, 1.0, 2.0):
        expected = -math.log(2 / (c + 1)) - math.log(2 * c / (c + 1))
        torch.testing.assert_close(
            _constant_loss(c)(batch)["loss_density_ratio"], torch.tensor(expected)
        )
    # identical points in both parts: the loss is smallest at w = 1
    batch = TensorDict(
        observation=torch.zeros(10, OBS),
        action=torch.zeros(10, ACT),
        online=torch.arange(10) < 5,
        batch_size=[10],
    )
    values = {
        c: float(_constant_loss(c)(batch)["loss_density_ratio"].detach()) for c in (0.8, 1.0, 1.25)
    }
    assert values[1.0] < values[0.8] and values[1.0] < values[1.25]


def test_gradients_reach_only_the_ratio_network():
    loss = _constant_loss(2.0)
    gen = torch.Generator().manual_seed(0)
    batch = _gaussian_batch(8, torch.ones(OBS + ACT), gen=gen)
    loss(batch)["loss_density_ratio"].backward()
    (param,) = loss.parameters()
    # dL/dc = 1/(c+1) − (1/c − 1/(c+1)) = 1/3 − 1/6
    torch.testing.assert_close(param.grad, torch.tensor(1 / 3 - 1 / 6))


def test_ratio_network_learns_to_separate_two_gaussians():
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    shift = torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0])
    loss = DensityRatioLoss(make_density_ratio_network(OBS, ACT, num_cells=(32, 32)))
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-3)
    for _ in range(300):
        value = loss(_gaussian_batch(128, shift, gen=gen))["loss_density_ratio"]
        optimizer.zero_grad()
        value.backward()
        optimizer.step()

    test = _gaussian_batch(1000, shift, gen=gen)
    with torch.no_grad(), loss.ratio_network_params.to_module(loss.ratio_network):
        w = loss.ratio_network(test)["density_ratio"].squeeze(-1)
    x = torch.cat([test["observation"], test["action"]], -1)
    true_log_ratio = x @ shift - shift.square().sum() / 2  # log N(x; shift, I) / N(x; 0, I)
    online = test["online"]
    assert float(w[online].mean()) > 3 * float(w[~online].mean())
    ranks = lambda v: v.argsort().argsort().float()  # noqa: E731
    spearman = torch.corrcoef(torch.stack([ranks(w), ranks(true_log_ratio)]))[0, 1]
    assert spearman > 0.85
    # calibrated: the mean of w over D_offline estimates E_off[d_on / d_off] = 1
    assert 0.6 < float(w[~online].mean()) < 1.6


def test_a_batch_without_both_parts_names_the_fix():
    batch = TensorDict(
        observation=torch.zeros(4, OBS),
        action=torch.zeros(4, ACT),
        online=torch.zeros(4, dtype=torch.bool),
        batch_size=[4],
    )
    with pytest.raises(ValueError, match="ratio_batch"):
        _constant_loss(1.0)(batch)
    with pytest.raises(KeyError, match="set_keys"):
        _constant_loss(1.0)(batch.exclude("online"))


def test_an_all_online_batch_is_refused_too_and_the_messages_name_the_fix():
    batch = TensorDict(
        observation=torch.zeros(4, OBS),
        action=torch.zeros(4, ACT),
        online=torch.ones(4, dtype=torch.bool),
        batch_size=[4],
    )
    with pytest.raises(
        ValueError,
        match=r"^DensityRatioLoss needs offline and online transitions in the batch; got 4 "
        r"online of 4\. Use BalancedReplayBuffer\.ratio_batch\(\) once the online buffer "
        r"holds data\.$",
    ):
        _constant_loss(1.0)(batch)
    with pytest.raises(KeyError, match=r"loss's online entry.*set_keys\(online=\.\.\.\)"):
        _constant_loss(1.0)(batch.exclude("online"))


class _FirstCoordinate(nn.Module):
    """A fake ratio network ``w(s, a) = s_0`` (the test chooses ``s_0 ≥ 0``)."""

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return observation[..., :1]


def test_per_sample_ratios_give_the_loss_and_the_mean_ratio_of_each_part():
    net = TensorDictModule(
        _FirstCoordinate(), in_keys=["observation", "action"], out_keys=["density_ratio"]
    )
    w = [1.0, 2.0, 3.0, 4.0, 5.0]
    online = [True, False, True, False, False]
    observation = torch.zeros(5, OBS)
    observation[:, 0] = torch.tensor(w)
    batch = TensorDict(
        observation=observation,
        action=torch.zeros(5, ACT),
        online=torch.tensor(online),
        batch_size=[5],
    )
    out = DensityRatioLoss(net)(batch)
    off_w = [x for x, o in zip(w, online, strict=True) if not o]
    on_w = [x for x, o in zip(w, online, strict=True) if o]
    expected = sum(-math.log(2 / (x + 1)) for x in off_w) / len(off_w) - sum(
        math.log(2 * x / (x + 1)) for x in on_w
    ) / len(on_w)
    torch.testing.assert_close(out["loss_density_ratio"], torch.tensor(expected))
    torch.testing.assert_close(out["ratio_online"], torch.tensor(2.0))  # (1 + 3) / 2
    torch.testing.assert_close(out["ratio_offline"], torch.tensor(11 / 3))  # (2 + 4 + 5) / 3
    assert out.batch_size == torch.Size([])


def test_reduction_none_gives_one_term_per_transition_whose_mean_is_the_loss():
    """Per transition: ``(N / N_off) · (−log(2 / (w + 1)))`` offline and ``−(N / N_on) ·
    log(2w / (w + 1))`` online, by hand on five ratios; mean = the default loss, sum = N ×."""
    net = TensorDictModule(
        _FirstCoordinate(), in_keys=["observation", "action"], out_keys=["density_ratio"]
    )
    w, online = [1.0, 2.0, 3.0, 4.0, 5.0], [True, False, True, False, False]
    observation = torch.zeros(5, OBS)
    observation[:, 0] = torch.tensor(w)
    batch = TensorDict(
        observation=observation, action=torch.zeros(5, ACT), online=torch.tensor(online),
        batch_size=[5],
    )  # fmt: skip
    by_hand = torch.tensor(
        [-5 / 2 * math.log(2 * x / (x + 1)) if o else -5 / 3 * math.log(2 / (x + 1))
         for x, o in zip(w, online, strict=True)]
    )  # fmt: skip
    per_sample = DensityRatioLoss(net, reduction="none")(batch)["loss_density_ratio"]
    torch.testing.assert_close(per_sample, by_hand)
    mean = DensityRatioLoss(net)(batch)["loss_density_ratio"]
    torch.testing.assert_close(per_sample.mean(), mean)
    summed = DensityRatioLoss(net, reduction="sum")(batch)["loss_density_ratio"]
    torch.testing.assert_close(summed, 5 * mean)
    with pytest.raises(ValueError, match="reduction must be 'mean', 'sum' or 'none'"):
        DensityRatioLoss(net, reduction="max")


def test_the_log_guard_keeps_the_loss_finite_at_zero_and_huge_ratios():
    """``_LOG_EPS = 1e-10`` is added inside both logarithms (the authors' guard): ``w = 0``
    online gives ``log(1e-10)``, ``w = 1e11`` offline ``−log(2 / (1e11 + 1) + 1e-10)``."""
    eps = 1e-10
    online = torch.arange(6) < 3
    batch = TensorDict(
        observation=torch.zeros(6, OBS), action=torch.zeros(6, ACT), online=online, batch_size=[6]
    )
    expected = -math.log(2.0 + eps) - math.log(eps)
    torch.testing.assert_close(
        _constant_loss(0.0)(batch)["loss_density_ratio"], torch.tensor(expected)
    )
    big = 1e11
    expected = -math.log(2 / (big + 1) + eps) - math.log(2 * big / (big + 1) + eps)
    torch.testing.assert_close(
        _constant_loss(big)(batch)["loss_density_ratio"], torch.tensor(expected)
    )


def test_the_network_is_an_mlp_on_the_concatenated_state_action_with_output_bias_one():
    """``w = relu(W₂ relu(W₁ [s, a] + b₁) + b₂)`` with ``b₂ = 1`` at initialisation; it
    evaluates any leading batch shape."""
    torch.manual_seed(0)
    net = make_density_ratio_network(OBS, ACT, num_cells=(8,))
    mlp = net.module.mlp
    assert sum(p.numel() for p in net.parameters()) == (OBS + ACT) * 8 + 8 + 8 + 1
    torch.testing.assert_close(mlp[-1].bias, torch.ones(1))
    s, a = torch.randn(2, 4, OBS), torch.randn(2, 4, ACT)
    w = net(TensorDict(observation=s, action=a, batch_size=[2, 4]))["density_ratio"]
    (w1, b1), (w2, b2) = (mlp[0].weight, mlp[0].bias), (mlp[-1].weight, mlp[-1].bias)
    x = torch.cat([s, a], -1)
    expected = torch.relu(torch.relu(x @ w1.T + b1) @ w2.T + b2)
    assert w.shape == (2, 4, 1)
    torch.testing.assert_close(w, expected)
    # with the last layer's weights zeroed, w is the bias: 1 everywhere (no preference)
    with torch.no_grad():
        mlp[-1].weight.zero_()
    w = net(TensorDict(observation=s, action=a, batch_size=[2, 4]))["density_ratio"]
    torch.testing.assert_close(w, torch.ones(2, 4, 1))


def test_the_loss_compiles_without_a_graph_break_and_keeps_its_value():
    """Masked sums instead of boolean indexing: no data-dependent shape (issue 30)."""
    from tensordict import TensorDict as _TD

    from torchrl_dual.objectives.density_ratio import DensityRatioLoss as _Loss
    from torchrl_dual.objectives.density_ratio import make_density_ratio_network as _net

    torch.manual_seed(0)
    loss = _Loss(_net(3, 2, num_cells=(8,)))
    td = _TD(observation=torch.randn(9, 3), action=torch.randn(9, 2),
             online=torch.arange(9) % 3 == 0, batch_size=[9])  # fmt: skip
    eager = loss(td)
    torch._dynamo.reset()
    compiled = torch.compile(loss, fullgraph=True, backend="eager")(td)
    for key in ("loss_density_ratio", "ratio_offline", "ratio_online"):
        torch.testing.assert_close(compiled[key], eager[key])
    with torch.no_grad():
        w = loss.ratio_network(td)["density_ratio"].squeeze(-1)
    torch.testing.assert_close(eager["ratio_online"], w[td["online"]].mean())
    torch.testing.assert_close(eager["ratio_offline"], w[~td["online"]].mean())
