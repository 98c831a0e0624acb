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
