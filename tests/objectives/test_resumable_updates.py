"""An update loop checkpointed within (``run_updates``' and ``progressive_distillation``'s
``checkpoints``) and resumed from its saved state ends bitwise as the loop never stopped:
weights, optimizer, learning-rate schedule, EMA and the logged window averages."""

from __future__ import annotations

import copy
import io

import pytest
import torch

from torchrl_dual.objectives import (
    DiffusionPlannerLoss,
    ExponentialMovingAverage,
    progressive_distillation,
    run_updates,
)


class _Stopper:
    """:class:`~torchrl_dual.objectives.UpdateCheckpoints` that saves the loop state and
    torch's random state (through ``torch.save``, as a checkpoint file would) after update
    ``stop_at`` and stops there as Ctrl-C would; built with ``saved``, it resumes from it."""

    def __init__(self, stop_at: int | None = None, saved: bytes | None = None) -> None:
        self.stop_at, self.saved, self.seen = stop_at, saved, []

    def resume(self):
        if self.saved is None:
            return None
        state = torch.load(io.BytesIO(self.saved), weights_only=False)
        torch.set_rng_state(state["rng"])
        return state["loop"]

    def after_update(self, done, total, state):
        self.seen.append((done, total))
        if done == self.stop_at:
            buffer = io.BytesIO()
            torch.save({"loop": state(), "rng": torch.get_rng_state()}, buffer)
            self.saved = buffer.getvalue()
            raise KeyboardInterrupt


class _Logger:
    def __init__(self) -> None:
        self.records: list[tuple[str, float, int]] = []

    def log_scalar(self, name, value, step=None):
        self.records.append((name, value, step))


def _sampler(make_windows):
    windows = make_windows(batch=32, seed=3)
    return lambda: windows[torch.randint(0, 32, (8,))]


def _states_equal(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize("stop_at", [1, 4, 5, 7])
def test_a_planner_loop_stopped_and_resumed_ends_as_the_uninterrupted_one(
    stop_at, make_model, make_windows
):
    sample, initial = _sampler(make_windows), make_model(num_steps=4)

    def updates(model, checkpoints, logger):
        loss = DiffusionPlannerLoss(model)
        optimizer = torch.optim.Adam(loss.parameters(), lr=1e-3)
        ema = ExponentialMovingAverage(model, 0.9)
        kwargs = dict(cosine_lr=True, ema=ema, logger=logger, log_every=3, progress=False)
        averages = run_updates(loss, sample, 7, optimizer, checkpoints=checkpoints, **kwargs)
        return averages, optimizer, ema

    torch.manual_seed(0)
    whole, whole_log = copy.deepcopy(initial), _Logger()
    averages, optimizer, ema = updates(whole, None, whole_log)

    torch.manual_seed(0)
    first, log = copy.deepcopy(initial), _Logger()
    stopper = _Stopper(stop_at)
    with pytest.raises(KeyboardInterrupt):
        updates(first, stopper, log)
    assert stopper.seen == [(k, 7) for k in range(1, stop_at + 1)]
    torch.manual_seed(123)  # a resumed run's generator: the saved state replaces it
    resumed = copy.deepcopy(initial)  # a new process: the initial weights, then the saved
    resumed_stopper = _Stopper(saved=stopper.saved)
    got_averages, got_optimizer, got_ema = updates(resumed, resumed_stopper, log)

    assert resumed_stopper.seen == [(k, 7) for k in range(stop_at + 1, 8)]
    assert _states_equal(resumed, whole)
    assert got_averages == averages and log.records == whole_log.records
    assert got_optimizer.param_groups[0]["lr"] == optimizer.param_groups[0]["lr"]
    assert all(torch.equal(a, b) for a, b in zip(got_ema.shadow, ema.shadow, strict=True))


@pytest.mark.parametrize("stop_at", [2, 5, 7, 10])  # in rounds 1, 2 (and at its end), 3
def test_a_distillation_stopped_in_any_round_and_resumed_ends_as_the_uninterrupted_one(
    stop_at, make_model, make_windows
):
    sample, teacher = _sampler(make_windows), make_model(num_steps=8)

    def distil(checkpoints):
        return progressive_distillation(
            teacher, sample, [3, 4, 3], progress=False, checkpoints=checkpoints
        )

    torch.manual_seed(0)
    whole = distil(None)
    torch.manual_seed(0)
    stopper = _Stopper(stop_at)
    with pytest.raises(KeyboardInterrupt):
        distil(stopper)
    assert stopper.seen == [(k, 10) for k in range(1, stop_at + 1)]
    torch.manual_seed(123)
    resumed_stopper = _Stopper(saved=stopper.saved)
    resumed = distil(resumed_stopper)

    assert resumed_stopper.seen == [(k, 10) for k in range(stop_at + 1, 11)]
    assert resumed.num_steps == whole.num_steps == 1
    assert _states_equal(resumed, whole)
