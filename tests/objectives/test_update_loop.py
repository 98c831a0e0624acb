"""Tests of ``run_updates`` and ``ExponentialMovingAverage``
(``torchrl_dual/objectives/update_loop.py``), the loop every training driver shares."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from torchrl_dual.objectives import ExponentialMovingAverage, run_updates


class _Quadratic(nn.Module):
    """``loss_fit = ½ Σ w²`` (gradient ``w``) plus two diagnostics: ``metric``, the call
    index, and ``penalty``, a parameter-dependent entry that is not a loss."""

    def __init__(self, start: float = 1.0) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.full((2,), start))
        self.calls = 0

    def forward(self, batch) -> TensorDict:
        self.calls += 1
        return TensorDict(
            loss_fit=0.5 * self.w.square().sum(),
            metric=torch.tensor(float(self.calls)),
            penalty=1e3 * self.w.sum(),
            batch_size=[],
        )


class _Logger:
    def __init__(self) -> None:
        self.records: list[tuple[str, float, int]] = []

    def log_scalar(self, name, value, step=None):
        self.records.append((name, value, step))


def _run(module, num_updates, *, lr=0.1, **kwargs):
    optimizer = torch.optim.SGD(module.parameters(), lr=lr)
    kwargs.setdefault("progress", False)
    return run_updates(module, lambda: None, num_updates, optimizer, **kwargs), optimizer


# ----------------------------------------------------------------------------- run_updates
def test_each_update_is_one_gradient_step_on_the_sum_of_the_loss_entries_only():
    module = _Quadratic(start=1.0)
    _run(module, 3, lr=0.1, grad_clip=None)
    assert module.calls == 3
    # w ← w − 0.1 w per step; the 1e3 · Σw "penalty" entry is not a loss and adds nothing
    torch.testing.assert_close(module.w.detach(), torch.full((2,), 0.9**3))


def test_scalar_entries_are_averaged_per_logging_window_and_the_last_window_returned():
    module = _Quadratic()
    logger = _Logger()
    stats, _ = _run(module, 5, logger=logger, log_prefix="fit/", log_every=2, step_offset=10)
    metric = [(value, step) for name, value, step in logger.records if name == "fit/metric"]
    assert metric == [(1.5, 12), (3.5, 14), (5.0, 15)]  # windows [1, 2], [3, 4], [5]
    assert stats["metric"] == 5.0
    assert set(stats) == {"loss_fit", "metric", "penalty"}
    assert {name for name, _, _ in logger.records} == {"fit/loss_fit", "fit/metric", "fit/penalty"}


def test_gradients_are_clipped_to_the_given_norm():
    module = _Quadratic(start=100.0)  # gradient norm 100·√2
    _run(module, 1, lr=1.0, grad_clip=1.0)
    torch.testing.assert_close(module.w.detach(), torch.full((2,), 100.0 - 2**-0.5))
    unclipped = _Quadratic(start=100.0)
    _run(unclipped, 1, lr=1.0, grad_clip=None)
    torch.testing.assert_close(unclipped.w.detach(), torch.zeros(2))


def test_the_cosine_schedule_anneals_the_learning_rate_to_zero():
    _, optimizer = _run(_Quadratic(), 4, lr=0.1, cosine_lr=True)
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.0, abs=1e-12)
    _, optimizer = _run(_Quadratic(), 4, lr=0.1)
    assert optimizer.param_groups[0]["lr"] == 0.1


def test_the_ema_is_updated_after_every_step():
    module = _Quadratic(start=1.0)
    ema = ExponentialMovingAverage(module, decay=0.5)
    _run(module, 2, lr=0.5, grad_clip=None, ema=ema)
    # w: 1 → 0.5 → 0.25; shadow: 1 → 0.75 → 0.5
    torch.testing.assert_close(module.w.detach(), torch.full((2,), 0.25))
    torch.testing.assert_close(ema.shadow[0], torch.full((2,), 0.5))


# ----------------------------------------------------------------------------- EMA
def test_the_ema_is_a_lerp_towards_the_current_weights_and_copies_back():
    net = nn.Linear(2, 1)
    start = [p.detach().clone() for p in net.parameters()]
    ema = ExponentialMovingAverage(net, decay=0.9)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(1.0)
    ema.update()
    for average, before in zip(ema.shadow, start, strict=True):
        torch.testing.assert_close(average, before + 0.1)
    ema.copy_to(net)
    for p, before in zip(net.parameters(), start, strict=True):
        torch.testing.assert_close(p.detach(), before + 0.1)
    assert all(
        a.data_ptr() != p.data_ptr() for a, p in zip(ema.shadow, net.parameters(), strict=True)
    )


@pytest.mark.parametrize("decay", [1.0, -0.1, 1.5])
def test_a_decay_outside_zero_one_is_rejected(decay):
    with pytest.raises(ValueError, match=rf"EMA decay must lie in \[0, 1\), got {decay}"):
        ExponentialMovingAverage(nn.Linear(2, 1), decay=decay)
