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


class _Target(nn.Module):
    """``loss_fit = ½ Σ (w − batch["target"])²``: one SGD step with lr 1 lands on the target."""

    def __init__(self) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.zeros(2))

    def forward(self, batch) -> TensorDict:
        return TensorDict(loss_fit=0.5 * (self.w - batch["target"]).square().sum(), batch_size=[])


def test_each_update_trains_on_a_fresh_batch_from_sample():
    targets = iter([3.0, 5.0])
    drawn = []

    def sample():
        drawn.append(next(targets))
        return TensorDict(target=torch.full((2,), drawn[-1]), batch_size=[])

    module = _Target()
    optimizer = torch.optim.SGD(module.parameters(), lr=1.0)
    run_updates(module, sample, 2, optimizer, grad_clip=None, progress=False)
    assert drawn == [3.0, 5.0]
    torch.testing.assert_close(module.w.detach(), torch.full((2,), 5.0))  # 0 → 3 → 5


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


class _FirstCallOnly(nn.Module):
    """``loss_fit = Σ u`` on the first call only; later calls give ``u`` no gradient."""

    def __init__(self) -> None:
        super().__init__()
        self.u = nn.Parameter(torch.ones(2))
        self.w = nn.Parameter(torch.ones(2))
        self.calls = 0

    def forward(self, batch) -> TensorDict:
        self.calls += 1
        loss = self.w.sum() + (self.u.sum() if self.calls == 1 else 0.0)
        return TensorDict(loss_fit=loss, batch_size=[])


def test_a_parameter_without_gradient_in_a_step_is_left_alone_by_the_optimizer():
    """Gradients are reset to ``None`` (not zeros) before each step, so SGD skips a parameter
    the step's loss does not reach, weight decay included: ``u`` 1 → 1 − 0.1·(1 + 1) = 0.8,
    then stays (with zeroed gradients the decay would take it to 0.72)."""
    module = _FirstCallOnly()
    optimizer = torch.optim.SGD(module.parameters(), lr=0.1, weight_decay=1.0)
    run_updates(module, lambda: None, 2, optimizer, grad_clip=None, progress=False)
    torch.testing.assert_close(module.u.detach(), torch.full((2,), 0.8))
    assert module.u.grad is None


def test_the_default_grad_clip_is_a_norm_of_one():
    module = _Quadratic(start=100.0)  # gradient norm 100·√2
    optimizer = torch.optim.SGD(module.parameters(), lr=1.0)
    run_updates(module, lambda: None, 1, optimizer, progress=False)
    torch.testing.assert_close(module.w.detach(), torch.full((2,), 100.0 - 2**-0.5))


def test_the_default_logging_window_is_100_updates():
    logger = _Logger()
    _run(_Quadratic(), 101, lr=0.0, logger=logger)
    metric = [(value, step) for name, value, step in logger.records if name == "metric"]
    assert metric == [(50.5, 100), (101.0, 101)]  # mean of 1..100, then the 101st alone


def test_zero_updates_return_an_empty_dict_and_log_nothing():
    logger = _Logger()
    stats, optimizer = _run(_Quadratic(), 0, logger=logger, cosine_lr=True)
    assert stats == {}
    assert logger.records == []
    assert optimizer.param_groups[0]["lr"] == 0.1


def test_the_cosine_schedule_of_a_single_update_ends_at_zero():
    _, optimizer = _run(_Quadratic(), 1, lr=0.1, cosine_lr=True)
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.0, abs=1e-12)


def test_the_progress_bar_is_shown_by_default_with_the_loss_averages_and_then_erased(capsys):
    """The default bar: described ``updates``, the last window's ``loss_*`` averages as
    postfix (4 decimals; not the other entries), erased at the end (``leave=False``)."""
    module = _Quadratic(start=1.0)
    optimizer = torch.optim.SGD(module.parameters(), lr=0.1)
    run_updates(module, lambda: None, 3, optimizer, grad_clip=None)
    err = capsys.readouterr().err
    assert err.startswith("\rupdates:")
    # loss_fit = Σw²/2 = 1, 0.81, 0.6561 (w = 1, 0.9, 0.81): mean 0.82203
    assert "loss_fit=0.8220" in err
    assert "metric" not in err and "penalty" not in err
    assert err.endswith("\r") and "\n" not in err  # erased, no line left behind


def test_progress_false_prints_nothing(capsys):
    _run(_Quadratic(), 3, progress=False)
    assert capsys.readouterr().err == ""


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


def test_the_ema_decay_defaults_to_0_999_and_zero_copies_the_weights():
    net = nn.Linear(2, 1)
    start = [p.detach().clone() for p in net.parameters()]
    ema, copy = ExponentialMovingAverage(net), ExponentialMovingAverage(net, decay=0.0)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(1.0)
    ema.update()
    copy.update()
    for average, copied, before in zip(ema.shadow, copy.shadow, start, strict=True):
        torch.testing.assert_close(average, before + 0.001)
        torch.testing.assert_close(copied, before + 1.0)


@pytest.mark.parametrize("decay", [1.0, -0.1, 1.5])
def test_a_decay_outside_zero_one_is_rejected(decay):
    with pytest.raises(ValueError, match=rf"EMA decay must lie in \[0, 1\), got {decay}"):
        ExponentialMovingAverage(nn.Linear(2, 1), decay=decay)
