"""Tests of ``DiffusionPlannerLoss`` and the ``train_planner`` driver
(``torchrl_dual/objectives/diffusion_planner.py``, Eq. 3, Algorithm 1 lines 3-4)."""

from __future__ import annotations

import statistics

import pytest
import torch
from torch import nn
from toy import identity_statistics

from torchrl_dual.diffusion import TrajectoryDiffusion
from torchrl_dual.objectives import DiffusionPlannerLoss, train_planner


def _as_fitted(model: TrajectoryDiffusion) -> TrajectoryDiffusion:
    identity_statistics(model.normalizer)
    return model


pytestmark = pytest.mark.usefixtures("seeded")


class MaskSpy(nn.Module):
    """A denoiser that predicts ``v̂ = 0`` and records the mask it was given."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = nn.Parameter(torch.zeros(()))
        self.masks: list[torch.Tensor] = []

    def forward(self, z, t, mask):
        self.masks.append(mask.detach().clone())
        return self.scale * z


def test_forward_returns_every_out_key_as_a_finite_scalar(make_model, make_windows):
    loss_fn = DiffusionPlannerLoss(make_model())
    out = loss_fn(make_windows())
    assert set(out.keys()) == set(loss_fn.out_keys)
    for key in loss_fn.out_keys:
        assert out[key].shape == () and torch.isfinite(out[key])


def test_loss_gives_gradients_to_every_denoiser_parameter(make_model, make_windows):
    model = make_model()
    loss_fn = DiffusionPlannerLoss(model)
    assert {id(p) for p in loss_fn.parameters()} == {id(p) for p in model.parameters()}
    loss_fn(make_windows())["loss_diffusion"].backward()
    for name, param in model.denoiser.named_parameters():
        assert param.grad is not None, name
        assert param.grad.abs().sum() > 0, name
    assert not any(buffer.requires_grad for buffer in model.normalizer.buffers())


def test_the_input_tensordict_is_not_modified(make_model, make_windows, td_steady):
    windows = make_windows()
    before = windows.clone()
    DiffusionPlannerLoss(make_model())(windows)
    td_steady(before, windows)


def test_set_keys_reads_windows_stored_under_other_keys(make_model, make_windows):
    model = make_model()
    default = DiffusionPlannerLoss(model)
    renamed = DiffusionPlannerLoss(model)
    renamed.set_keys(observation=("agent", "obs"), action="act")
    torch.manual_seed(5)
    expected = default(make_windows(seed=2))["loss_diffusion"]
    torch.manual_seed(5)
    windows = make_windows(seed=2, observation_key=("agent", "obs"), action_key="act")
    assert torch.equal(renamed(windows)["loss_diffusion"], expected)
    assert renamed.in_keys == [("agent", "obs"), "act"]


def test_set_keys_rejects_an_unknown_key_name(make_model):
    loss_fn = DiffusionPlannerLoss(make_model())
    with pytest.raises(ValueError, match="obs is not an accepted tensordict key"):
        loss_fn.set_keys(obs="observation")


@pytest.mark.parametrize("mask_key", ["condition_mask", ("masks", "known")])
def test_a_provided_condition_mask_is_passed_to_the_denoiser(mask_key, make_layout, make_windows):
    layout = make_layout()
    spy = MaskSpy()
    loss_fn = DiffusionPlannerLoss(_as_fitted(TrajectoryDiffusion(layout, spy)))
    if mask_key != "condition_mask":
        loss_fn.set_keys(condition_mask=mask_key)
    windows = make_windows()
    mask = torch.rand(windows.shape[0], *layout.window_shape) < 0.5
    windows.set(mask_key, mask)
    loss_fn(windows)
    assert torch.equal(spy.masks[-1], mask)


def test_without_a_mask_s0_is_always_known_and_a0_with_the_given_probability(
    make_layout, make_windows
):
    layout = make_layout()
    spy = MaskSpy()
    DiffusionPlannerLoss(_as_fitted(TrajectoryDiffusion(layout, spy)), action_condition_prob=0.5)(
        make_windows(batch=400)
    )
    mask = spy.masks[-1]
    s0, s0_a0 = layout.condition_mask("s0"), layout.condition_mask("s0_a0")
    assert (mask[:, 0, : layout.obs_dim]).all()
    is_s0, is_s0_a0 = (mask == s0).flatten(1).all(1), (mask == s0_a0).flatten(1).all(1)
    assert (is_s0 | is_s0_a0).all()
    assert 0.4 < is_s0_a0.float().mean() < 0.6


def test_a_full_condition_mask_leaves_nothing_to_generate_and_zero_loss(make_model, make_windows):
    model = make_model()
    windows = make_windows()
    windows["condition_mask"] = torch.ones(windows.shape[0], *model.layout.window_shape, dtype=bool)
    out = DiffusionPlannerLoss(model)(windows)
    assert out["loss_diffusion"].detach().item() == 0.0 and out["x0_error"].item() == 0.0


@pytest.mark.parametrize("reduction", ["none", "mean", "sum"])
def test_reduction_gives_the_documented_shape(reduction, make_model, make_windows):
    loss_fn = DiffusionPlannerLoss(make_model(), reduction=reduction)
    torch.manual_seed(7)
    loss = loss_fn(make_windows(batch=6))["loss_diffusion"]
    torch.manual_seed(7)
    per_window = DiffusionPlannerLoss(loss_fn.model, reduction="none")(make_windows(batch=6))
    per_window = per_window["loss_diffusion"]
    assert per_window.shape == (6,)
    expected = {"none": per_window, "mean": per_window.mean(), "sum": per_window.sum()}
    torch.testing.assert_close(loss, expected[reduction])


def test_missing_key_error_names_the_key_and_the_fix(make_model, make_windows):
    windows = make_windows().exclude("action")
    with pytest.raises(
        KeyError,
        match=r"The loss's action entry reads 'action', which the input lacks; it holds "
        r"\['observation'\]\. Rename the entry or call loss.set_keys\(action=\.\.\.\)",
    ):
        DiffusionPlannerLoss(make_model())(windows)


def test_a_wrong_last_dimension_shows_expected_and_given_shapes(make_model, make_windows):
    windows = make_windows()
    windows["observation"] = torch.randn(8, 5, 4)
    with pytest.raises(
        ValueError, match=r"observation must have shape \[batch, 5, 3\].*\(8, 5, 4\)"
    ):
        DiffusionPlannerLoss(make_model())(windows)


def test_a_wrong_window_length_shows_expected_and_given_shapes(make_model, make_windows):
    short = make_windows()[:, :3]
    with pytest.raises(ValueError, match=r"H \+ 1 = 5 steps.*got \(8, 3, 3\)"):
        DiffusionPlannerLoss(make_model())(short)


def test_unbatched_windows_are_rejected(make_model, make_windows):
    with pytest.raises(ValueError, match=r"\[batch, 5, 3\].*got \(5, 3\)"):
        DiffusionPlannerLoss(make_model())(make_windows()[0])


@pytest.mark.parametrize("key", ["observation", "action"])
def test_nan_input_error_counts_the_bad_entries(key, make_model, make_windows):
    windows = make_windows()
    windows[key][0, 1, 0] = float("nan")
    windows[key][3, 2, 1] = float("inf")
    with pytest.raises(ValueError, match=rf"{key} holds 2 NaN/inf entries"):
        DiffusionPlannerLoss(make_model())(windows)


@pytest.mark.parametrize(
    "mask", [torch.ones(8, 5, 5), torch.ones(8, 5, 4, dtype=torch.bool)], ids=["float", "shape"]
)
def test_a_malformed_condition_mask_is_rejected(mask, make_model, make_windows):
    windows = make_windows()
    windows["condition_mask"] = mask
    with pytest.raises(ValueError, match=r"boolean mask ending with \(5, 5\)"):
        DiffusionPlannerLoss(make_model())(windows)


@pytest.mark.parametrize("prob", [-0.1, 1.5])
def test_action_condition_prob_outside_zero_one_is_rejected(prob, make_model):
    with pytest.raises(ValueError, match="action_condition_prob must lie in"):
        DiffusionPlannerLoss(make_model(), action_condition_prob=prob)


def test_loss_decreases_when_trained_on_the_bimodal_toy_data(make_toy_setup, run_adam):
    model, buffer = make_toy_setup()
    history = run_adam(DiffusionPlannerLoss(model), buffer.sample, 300)
    first, last = statistics.mean(history[:50]), statistics.mean(history[-50:])
    assert last < 0.5 * first, (first, last)


def test_reset_parameters_recursive_reinitialises_the_denoiser(make_model):
    model = make_model()
    before = [p.detach().clone() for p in model.denoiser.parameters()]
    torch.manual_seed(1234)  # not the seed the weights were drawn with
    DiffusionPlannerLoss(model).reset_parameters_recursive()
    assert any(
        not torch.equal(a, p) for a, p in zip(before, model.denoiser.parameters(), strict=True)
    )


# ----------------------------------------------------------------------------- driver
def test_train_planner_runs_the_requested_updates_and_trains_the_model_in_place(
    make_model, make_windows
):
    model = make_model()
    before = model.denoiser.head.weight.detach().clone()
    calls = []

    def sample():
        calls.append(1)
        return make_windows(seed=len(calls))

    logged = []

    class Logger:
        def log_scalar(self, name, value, step=None):
            logged.append((name, step))

    stats = train_planner(model, sample, 5, logger=Logger(), log_every=2, progress=False)
    assert len(calls) == 5
    assert set(stats) == {"loss_diffusion", "x0_error"}
    assert not torch.equal(model.denoiser.head.weight, before)
    assert [step for name, step in logged if name == "loss_diffusion"] == [2, 4, 5]


@pytest.mark.parametrize("prob", [0.0, 1.0])
def test_action_condition_prob_accepts_both_ends(prob, make_model):
    assert (
        DiffusionPlannerLoss(make_model(), action_condition_prob=prob).action_condition_prob == prob
    )


def test_train_planner_builds_its_loss_and_adam_from_its_arguments(make_model, monkeypatch):
    """The defaults reach the loss and the optimizer: Adam at 3e-4, ``a_0`` given half the
    time, the bar named ``planner``; explicit values replace them."""
    from torchrl_dual.objectives import diffusion_planner as module

    seen = {}

    def record(loss, sample, num_updates, optimizer, **kwargs):
        seen.update(prob=loss.action_condition_prob, lr=optimizer.param_groups[0]["lr"], **kwargs)
        return {}

    monkeypatch.setattr(module, "run_updates", record)
    module.train_planner(make_model(), lambda: None, 1)
    assert (seen["prob"], seen["lr"], seen["desc"]) == (0.5, 3e-4, "planner")
    module.train_planner(make_model(), lambda: None, 1, lr=1e-3, action_condition_prob=0.25)
    assert (seen["prob"], seen["lr"]) == (0.25, 1e-3)


# ----------------------------------------------------------------------------- Eq. 3 by hand
class _LinearV(nn.Module):
    """``v̂ = c·z + d·t``: a denoiser whose output is known in closed form."""

    def __init__(self, c: float, d: float) -> None:
        super().__init__()
        self.c = nn.Parameter(torch.tensor(c))
        self.d = d

    def forward(self, z, t, mask):
        return self.c * z + self.d * t[..., None, None]


def _model_with_known_statistics(layout) -> TrajectoryDiffusion:
    model = TrajectoryDiffusion(layout, _LinearV(0.6, 0.5))
    norm = model.normalizer
    norm.obs_mean.copy_(torch.tensor([1.0, -2.0, 0.5]))
    norm.obs_std.copy_(torch.tensor([2.0, 0.5, 1.0]))
    norm.action_mean.copy_(torch.tensor([0.3, -0.1]))
    norm.action_std.copy_(torch.tensor([0.5, 2.0]))
    return _as_fitted(model)  # declared fitted with the statistics above


def _varied_masks(layout, batch: int) -> torch.Tensor:
    """Random known entries (``s_0`` always), one window with a single free entry and
    one with none, so the per-window free counts differ."""
    gen = torch.Generator().manual_seed(9)
    mask = torch.rand(batch, *layout.window_shape, generator=gen) < 0.4
    mask |= layout.condition_mask("s0")
    mask[0] = True
    mask[0, 3, 1] = False
    mask[1] = True
    return mask


def _masked_mean_by_hand(error, mask):
    out = []
    for e, m in zip(error, mask, strict=True):
        free = e[~m]
        out.append(free.mean() if free.numel() else torch.zeros((), dtype=e.dtype))
    return torch.stack(out)


def test_the_loss_is_eq_3_in_v_form_computed_by_hand(make_layout, make_windows):
    """Per window: the mean over the free entries of ``(v̂ − (α_t·ε − σ_t·x_0))²`` with
    ``x_0`` the normalized window, ``t ~ U(0, 1)`` per window, ``z_t = α_t·x_0 + σ_t·ε``
    (known entries written back) and ``α_t = cos(πt/2)``, ``σ_t = sin(πt/2)``; ``x0_error``
    is the batch mean of the free entries' ``(x̂ − x_0)²``, ``x̂ = α_t·z − σ_t·v̂``."""
    layout = make_layout()
    model = _model_with_known_statistics(layout)
    windows = make_windows(layout, batch=6)
    mask = _varied_masks(layout, 6)
    windows["condition_mask"] = mask
    norm = model.normalizer
    x0 = torch.cat(
        [
            (windows["observation"] - norm.obs_mean) / norm.obs_std,
            (windows["action"] - norm.action_mean) / norm.action_std,
        ],
        -1,
    )
    torch.manual_seed(21)
    t = torch.rand(6)
    eps = torch.randn(6, *layout.window_shape)
    alpha = torch.cos(torch.pi / 2 * t)[:, None, None]
    sigma = torch.sin(torch.pi / 2 * t)[:, None, None]
    z = torch.where(mask, x0, alpha * x0 + sigma * eps)
    v_hat = 0.6 * z + 0.5 * t[:, None, None]
    v = alpha * eps - sigma * x0
    x_hat = torch.where(mask, x0, alpha * z - sigma * v_hat)
    expected = _masked_mean_by_hand((v_hat - v) ** 2, mask)
    expected_x0_error = _masked_mean_by_hand((x_hat - x0) ** 2, mask).mean()

    torch.manual_seed(21)
    out = DiffusionPlannerLoss(model, reduction="none")(windows)
    assert out["loss_diffusion"].shape == (6,)
    torch.testing.assert_close(out["loss_diffusion"].detach(), expected)
    torch.testing.assert_close(out["x0_error"], expected_x0_error)
    assert expected[1] == 0 and expected[0] > 0  # nothing free, one entry free


def test_windows_of_another_dtype_than_the_planner_are_refused_naming_both(
    make_model, make_windows
):
    """No silent cast: float64 windows for a float32 planner are an error naming both
    dtypes and the two fixes; cast either way, the loss runs in that dtype."""
    loss_fn = DiffusionPlannerLoss(make_model())
    windows = make_windows()
    with pytest.raises(
        TypeError,
        match=r"^observation is torch.float64 but the planner's weights are torch.float32: cast "
        r"the batch \(batch.to\(torch.float32\)\) or the loss \(loss.to\(torch.float64\)\)\.$",
    ):
        loss_fn(windows.double())
    assert loss_fn(windows)["loss_diffusion"].dtype == torch.float32
    assert loss_fn.double()(windows.double())["loss_diffusion"].dtype == torch.float64


def test_an_unfitted_normalizer_is_refused(make_layout, make_windows):
    """A planner whose normalizer was never fitted would train on raw units."""
    loss_fn = DiffusionPlannerLoss(TrajectoryDiffusion(make_layout(), hidden=8, depth=1))
    with pytest.raises(RuntimeError, match=r"^Normalizer is not fitted: call normalizer.fit"):
        loss_fn(make_windows())


@pytest.mark.parametrize("key", ["observation", "action"])
def test_nan_input_error_tells_to_clean_the_data(key, make_model, make_windows):
    windows = make_windows()
    windows[key][2, 0, 0] = float("nan")
    with pytest.raises(
        ValueError, match=rf"^{key} holds 1 NaN/inf entries; clean the data first\.$"
    ):
        DiffusionPlannerLoss(make_model())(windows)


def test_random_draws_follow_the_data_device_not_torch_s_default_device(
    make_layout, make_windows, draws_follow_the_data
):
    """``t``, ``ε`` and the ``a_0``-known draw are made where the windows live."""
    layout = make_layout()
    loss_fn = DiffusionPlannerLoss(_as_fitted(TrajectoryDiffusion(layout, _LinearV(0.6, 0.5))))
    draws_follow_the_data(loss_fn, make_windows(layout), ("loss_diffusion", "x0_error"))
