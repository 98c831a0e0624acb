"""Tests of ``DistillationLoss`` and the ``progressive_distillation`` driver
(``torchrl_dual/objectives/distillation.py``, Algorithm 1 line 5)."""

from __future__ import annotations

import copy
import statistics

import pytest
import torch
from tensordict import TensorDict
from toy import identity_statistics

from torchrl_dual.diffusion import TrajectoryDiffusion
from torchrl_dual.objectives import DistillationLoss, progressive_distillation
from torchrl_dual.objectives import distillation as distillation_module

pytestmark = pytest.mark.usefixtures("seeded")


def _pair(make_model, teacher_steps=4, **kwargs):
    teacher = make_model(num_steps=teacher_steps, **kwargs)
    student = copy.deepcopy(teacher)
    student.num_steps = teacher_steps // 2
    return student, teacher


def _teacher_weights(loss: DistillationLoss) -> TensorDict:
    return TensorDict.from_module(loss.teacher)


def _state(module):
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def _assert_same_state(module, state):
    for key, value in module.state_dict().items():
        assert torch.equal(value, state[key]), f"{key} changed"


def test_forward_returns_every_out_key_as_a_finite_scalar(make_model, make_windows):
    loss_fn = DistillationLoss(*_pair(make_model))
    out = loss_fn(make_windows())
    assert set(out.keys()) == set(loss_fn.out_keys)
    for key in loss_fn.out_keys:
        assert out[key].shape == () and torch.isfinite(out[key])


@pytest.mark.parametrize("student_steps", [1, 4, 8])
def test_a_student_that_does_not_take_half_the_teacher_steps_is_rejected(student_steps, make_model):
    teacher = make_model(num_steps=4)
    student = copy.deepcopy(teacher)
    student.num_steps = student_steps
    with pytest.raises(
        ValueError, match=rf"teacher has 4, student {student_steps}; set student.num_steps = 2\.$"
    ):
        DistillationLoss(student, teacher)


def test_the_teacher_itself_cannot_be_the_student(make_model):
    model = make_model(num_steps=2)
    with pytest.raises(
        ValueError, match=r"^student and teacher must be distinct modules \(deepcopy"
    ):
        DistillationLoss(model, model)


def test_the_loss_keeps_a_frozen_private_copy_of_the_teacher_in_its_state(make_model):
    """The caller's teacher keeps its gradients and its weights; the loss's copy has
    neither parameters nor gradients, and its weights are saved with the loss."""
    student, teacher = _pair(make_model)
    loss = DistillationLoss(student, teacher)
    assert loss.action_condition_prob == 0.5
    assert all(p.requires_grad for p in teacher.parameters())
    assert loss.teacher is not teacher
    assert list(loss.teacher.parameters()) == []  # buffers only
    saved = {k: v for k, v in loss.state_dict().items() if k.startswith("teacher.")}
    weights = dict(teacher.named_parameters())
    assert set(saved) == {f"teacher.{k}" for k in teacher.state_dict()}
    for name, value in weights.items():
        torch.testing.assert_close(saved[f"teacher.{name}"], value.detach())
    with torch.no_grad():
        next(teacher.parameters()).add_(1.0)  # the caller's teacher changes later
    assert not torch.equal(saved[f"teacher.{next(iter(weights))}"], next(teacher.parameters()))


def test_only_the_student_receives_gradients_and_updates(make_model, make_windows):
    student, teacher = _pair(make_model)
    loss_fn = DistillationLoss(student, teacher)
    loss_params = {id(p) for p in loss_fn.parameters()}
    assert loss_params == {id(p) for p in student.parameters()}
    assert not loss_params & {id(p) for p in teacher.parameters()}
    teacher_state, teacher_buffers = _state(teacher), _teacher_weights(loss_fn).clone()
    student_state = _state(student)
    optimizer = torch.optim.Adam(loss_fn.parameters(), lr=1e-2)

    loss_fn(make_windows())["loss_distillation"].backward()
    for name, param in student.denoiser.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, name
    assert all(p.grad is None for p in teacher.parameters())
    assert all(t.grad is None for t in _teacher_weights(loss_fn).values(True, True))
    optimizer.step()

    _assert_same_state(teacher, teacher_state)
    assert (_teacher_weights(loss_fn) == teacher_buffers).all()
    changed = [k for k, v in student.state_dict().items() if not torch.equal(v, student_state[k])]
    assert any(k.startswith("denoiser.") for k in changed)


def test_an_optimizer_step_on_the_loss_leaves_the_teacher_and_its_targets_bit_identical(
    make_model, make_windows
):
    student, teacher = _pair(make_model)
    loss_fn = DistillationLoss(student, teacher)
    trainable = [p for p in loss_fn.parameters() if p.requires_grad]
    teacher_ptrs = {t.data_ptr() for t in _teacher_weights(loss_fn).values(True, True)}
    assert not teacher_ptrs & {p.data_ptr() for p in trainable}  # no shared storage
    assert not any(t.requires_grad for t in _teacher_weights(loss_fn).values(True, True))
    layout = teacher.layout
    cond, mask = layout.conditioned_window(torch.randn(4, layout.obs_dim))
    z = torch.where(mask, cond, torch.randn_like(cond))
    i = torch.full((4,), 2.0)
    target = loss_fn.teacher_target(z, i, cond, mask)
    buffers, student_state = _teacher_weights(loss_fn).clone(), _state(student)

    optimizer = torch.optim.SGD(trainable, lr=1.0)  # a large step: any leak would show
    for _ in range(2):
        optimizer.zero_grad()
        loss_fn(make_windows())["loss_distillation"].backward()
        optimizer.step()

    assert all(
        torch.equal(a, b)
        for a, b in zip(
            _teacher_weights(loss_fn).values(True, True), buffers.values(True, True), strict=True
        )
    )
    assert torch.equal(loss_fn.teacher_target(z, i, cond, mask), target)
    assert not torch.equal(student.denoiser.head.weight, student_state["denoiser.head.weight"])


def test_the_input_tensordict_is_not_modified(make_model, make_windows, td_steady):
    windows = make_windows()
    before = windows.clone()
    DistillationLoss(*_pair(make_model))(windows)
    td_steady(before, windows)


def test_set_keys_reads_windows_stored_under_other_keys(make_model, make_windows):
    student, teacher = _pair(make_model)
    default, renamed = DistillationLoss(student, teacher), DistillationLoss(student, teacher)
    renamed.set_keys(observation="obs", action=("agent", "act"))
    torch.manual_seed(5)
    expected = default(make_windows(seed=2))["loss_distillation"]
    torch.manual_seed(5)
    windows = make_windows(seed=2, observation_key="obs", action_key=("agent", "act"))
    assert torch.equal(renamed(windows)["loss_distillation"], expected)


def test_set_keys_rejects_an_unknown_key_name(make_model):
    loss_fn = DistillationLoss(*_pair(make_model))
    with pytest.raises(ValueError, match="teacher is not an accepted tensordict key"):
        loss_fn.set_keys(teacher="observation")


def test_a_full_condition_mask_leaves_nothing_to_distil_and_zero_loss(make_model, make_windows):
    loss_fn = DistillationLoss(*_pair(make_model))
    loss_fn.set_keys(condition_mask="known")
    windows = make_windows()
    windows["known"] = torch.ones(8, *loss_fn.student.layout.window_shape, dtype=torch.bool)
    out = loss_fn(windows)
    assert out["loss_distillation"].detach().item() == 0.0


def test_missing_key_error_names_the_key(make_model, make_windows):
    with pytest.raises(
        KeyError, match=r"observation entry reads 'observation'.*set_keys\(observation=\.\.\.\)"
    ):
        DistillationLoss(*_pair(make_model))(make_windows().exclude("observation"))


def test_malformed_windows_are_rejected_with_the_reason(make_model, make_windows):
    loss_fn = DistillationLoss(*_pair(make_model))
    with pytest.raises(ValueError, match=r"H \+ 1 = 5 steps.*got \(8, 4, 3\)"):
        loss_fn(make_windows()[:, :4])
    windows = make_windows()
    windows["action"] = torch.randn(8, 5, 3)
    with pytest.raises(ValueError, match=r"action must have shape \[batch, 5, 2\]"):
        loss_fn(windows)
    windows = make_windows()
    windows["action"][0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="action holds 1 NaN/inf entries"):
        loss_fn(windows)


@pytest.mark.parametrize("reduction", ["mean", "sum"])
def test_mean_and_sum_reduce_the_per_window_losses(make_model, make_windows, reduction):
    student, teacher = _pair(make_model)
    losses = {}
    for name in ("none", reduction):
        torch.manual_seed(11)  # the same t and ε draws for both
        loss_fn = DistillationLoss(student, teacher, reduction=name)
        losses[name] = loss_fn(make_windows(batch=6))["loss_distillation"]
    per_window = losses["none"]
    assert per_window.shape == (6,) and per_window.std() > 0
    expected = per_window.mean() if reduction == "mean" else per_window.sum()
    assert losses[reduction].shape == ()
    torch.testing.assert_close(losses[reduction], expected)


def test_the_one_step_student_target_is_the_two_step_teacher_sample(make_model):
    student, teacher = _pair(make_model, teacher_steps=2)
    loss_fn = DistillationLoss(student, teacher)
    layout = teacher.layout
    cond, mask = layout.conditioned_window(torch.randn(4, layout.obs_dim))
    z = torch.where(mask, cond, torch.randn_like(cond))
    target = loss_fn.teacher_target(z, torch.ones(4), cond, mask)
    expected = teacher.sample(cond, mask, num_steps=2, noise=z)
    torch.testing.assert_close(target, expected, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("i", [1.0, 2.0, 3.0, 4.0])
def test_one_student_ddim_step_to_the_target_lands_where_two_teacher_steps_do(i, make_model):
    student, teacher = _pair(make_model, teacher_steps=8)
    loss_fn = DistillationLoss(student, teacher)
    layout, k = teacher.layout, student.num_steps
    cond, mask = layout.conditioned_window(torch.randn(4, layout.obs_dim))
    z = torch.where(mask, cond, torch.randn_like(cond))
    t, s = torch.full((4,), i / k), torch.full((4,), (i - 1) / k)
    x_tilde = loss_fn.teacher_target(z, torch.full((4,), i), cond, mask)
    z_s_teacher = teacher.ddim_step(
        teacher.ddim_step(z, t, t - 0.5 / k, cond, mask), t - 0.5 / k, s, cond, mask
    )
    alpha_t, sigma_t = teacher._scales(t, z)
    alpha_s, sigma_s = teacher._scales(s, z)
    eps_tilde = (z - alpha_t * x_tilde) / sigma_t
    z_s_student = torch.where(mask, cond, alpha_s * x_tilde + sigma_s * eps_tilde)
    torch.testing.assert_close(z_s_student, z_s_teacher, atol=1e-4, rtol=1e-4)


def test_loss_decreases_when_trained_on_the_bimodal_toy_data(make_toy_setup, run_adam):
    from torchrl_dual.objectives import DiffusionPlannerLoss

    teacher, buffer = make_toy_setup(num_steps=2)
    run_adam(DiffusionPlannerLoss(teacher), buffer.sample, 100)
    student = copy.deepcopy(teacher)
    student.num_steps = 1
    history = run_adam(DistillationLoss(student, teacher), buffer.sample, 300)
    first, last = statistics.mean(history[:50]), statistics.mean(history[-50:])
    assert last < 0.5 * first, (first, last)


def test_reset_parameters_recursive_resets_the_student_and_leaves_the_teacher(make_model):
    student, teacher = _pair(make_model)
    teacher_state, student_state = _state(teacher), _state(student)
    torch.manual_seed(1234)  # not the seed the weights were drawn with
    DistillationLoss(student, teacher).reset_parameters_recursive()
    _assert_same_state(teacher, teacher_state)
    assert any(not torch.equal(v, student_state[k]) for k, v in student.state_dict().items())


# ----------------------------------------------------------------------------- driver
class _RecordingLogger:
    def __init__(self) -> None:
        self.names: list[str] = []

    def log_scalar(self, name, value, step=None):
        self.names.append(name)

    def rounds(self) -> dict[str, int]:
        """Logged ``loss_distillation`` entries per round prefix, in order."""
        counts: dict[str, int] = {}
        for name in self.names:
            prefix, key = name.split("/")
            if key == "loss_distillation":
                counts[prefix] = counts.get(prefix, 0) + 1
        return counts


def test_progressive_distillation_halves_32_to_1_and_leaves_the_teacher_unchanged(
    make_toy_setup,
):
    teacher, buffer = make_toy_setup(num_steps=32)
    teacher_state = _state(teacher)
    logger = _RecordingLogger()

    student = progressive_distillation(
        teacher, buffer.sample, 2, logger=logger, log_every=2, progress=False
    )

    assert student is not teacher and student.num_steps == 1
    assert teacher.num_steps == 32
    _assert_same_state(teacher, teacher_state)
    assert list(logger.rounds()) == [
        "distill_16",
        "distill_8",
        "distill_4",
        "distill_2",
        "distill_1",
    ]
    assert not torch.equal(student.denoiser.head.weight, teacher.denoiser.head.weight)
    assert torch.equal(student.normalizer.obs_mean, teacher.normalizer.obs_mean)
    cond, mask = student.layout.conditioned_window(torch.zeros(3, 1))
    assert torch.isfinite(student.sample(cond, mask)).all()


def test_progressive_distillation_stops_at_final_steps(make_toy_setup):
    teacher, buffer = make_toy_setup(num_steps=8)
    logger = _RecordingLogger()
    student = progressive_distillation(
        teacher, buffer.sample, 1, final_steps=2, logger=logger, log_every=1, progress=False
    )
    assert student.num_steps == 2
    assert list(logger.rounds()) == ["distill_4", "distill_2"]


def test_progressive_distillation_spends_the_given_updates_in_each_round(make_toy_setup):
    teacher, buffer = make_toy_setup(num_steps=8)
    calls = []

    def sample():
        calls.append(1)
        return buffer.sample()

    logger = _RecordingLogger()
    progressive_distillation(teacher, sample, [1, 3, 2], logger=logger, log_every=1, progress=False)
    assert len(calls) == 6
    assert logger.rounds() == {"distill_4": 1, "distill_2": 3, "distill_1": 2}


@pytest.mark.parametrize("ema_decay", [0.5, None])
def test_progressive_distillation_keeps_the_ema_student(make_toy_setup, monkeypatch, ema_decay):
    teacher, buffer = make_toy_setup(num_steps=2)
    averages, last_weights = [], []
    original = distillation_module.run_updates

    def recording_run_updates(loss, *args, ema=None, **kwargs):
        out = original(loss, *args, ema=ema, **kwargs)
        averages.append(ema)
        last_weights.append([p.detach().clone() for p in loss.student.parameters()])
        return out

    monkeypatch.setattr(distillation_module, "run_updates", recording_run_updates)
    student = progressive_distillation(
        teacher, buffer.sample, 3, ema_decay=ema_decay, lr=1e-2, progress=False
    )
    kept = [p.detach() for p in student.parameters()]
    if ema_decay is None:
        assert averages == [None]
        expected = last_weights[0]
    else:
        assert averages[0].decay == ema_decay
        expected = averages[0].shadow
        assert any(not torch.equal(a, b) for a, b in zip(expected, last_weights[0], strict=True))
    assert all(torch.equal(a, b) for a, b in zip(kept, expected, strict=True))


def test_progressive_distillation_rejects_a_wrong_number_of_round_budgets(make_model):
    with pytest.raises(
        ValueError, match=r"updates_per_round has 2 entries but distilling 8 -> 1 steps takes 3"
    ):
        progressive_distillation(make_model(num_steps=8), lambda: None, [1, 2], progress=False)


@pytest.mark.parametrize("final_steps", [0, 3, 16])
def test_progressive_distillation_rejects_a_final_steps_not_n_over_a_power_of_two(
    final_steps, make_model
):
    with pytest.raises(ValueError, match=rf"final_steps={final_steps} must be N / 2\^k"):
        progressive_distillation(make_model(num_steps=8), lambda: None, 1, final_steps=final_steps)


def test_progressive_distillation_passes_its_settings_to_each_round(make_model, monkeypatch):
    """Its defaults reach every round: Adam at 1e-4, ``a_0`` given half the time, a cosine
    learning rate, a bar per round named by its steps; the student's steps stay integers."""
    seen = []

    def record(loss, sample, num_updates, optimizer, **kwargs):
        seen.append(
            dict(
                prob=loss.action_condition_prob,
                lr=optimizer.param_groups[0]["lr"],
                steps=loss.student.num_steps,
                **kwargs,
            )
        )
        return {}

    monkeypatch.setattr(distillation_module, "run_updates", record)
    student = progressive_distillation(make_model(num_steps=4), lambda: None, 1, ema_decay=None)
    assert [s["desc"] for s in seen] == ["distil 4->2", "distil 2->1"]
    assert all(s["prob"] == 0.5 and s["lr"] == 1e-4 and s["cosine_lr"] is True for s in seen)
    assert all(s["progress"] is True for s in seen)
    assert type(student.num_steps) is int and student.num_steps == 1
    assert all(type(s["steps"]) is int for s in seen)
    seen.clear()
    progressive_distillation(
        make_model(num_steps=2), lambda: None, 1, lr=3e-3, action_condition_prob=0.0, progress=False
    )
    assert (seen[0]["prob"], seen[0]["lr"], seen[0]["progress"]) == (0.0, 3e-3, False)


def test_progressive_distillation_to_the_teacher_s_own_steps_runs_no_round(make_model):
    teacher = make_model(num_steps=8)
    student = progressive_distillation(teacher, lambda: None, [], final_steps=8)
    assert student.num_steps == 8


# ----------------------------------------------------------------------------- loss by hand
class _LinearV(torch.nn.Module):
    """``v̂ = c·z + d·t``: a denoiser whose output is known in closed form."""

    def __init__(self, c: float, d: float) -> None:
        super().__init__()
        self.c = torch.nn.Parameter(torch.tensor(c))
        self.d = d

    def forward(self, z, t, mask):
        return self.c * z + self.d * t[..., None, None]


def _scales_by_hand(t):
    """The cosine schedule ``(α_t, σ_t) = (cos(πt/2), sin(πt/2))``, per window."""
    return torch.cos(torch.pi / 2 * t)[:, None, None], torch.sin(torch.pi / 2 * t)[:, None, None]


def _masked_mean_by_hand(error, mask):
    out = []
    for e, m in zip(error, mask, strict=True):
        free = e[~m]
        out.append(free.mean() if free.numel() else torch.zeros((), dtype=e.dtype))
    return torch.stack(out)


def _distillation_by_hand(x0, mask, i, eps, k, teacher_cd, student_cd):
    """Section 3.1's round: ``z_t``, two teacher DDIM steps to ``z_s``, the one-step
    target ``x̃ = (z_s − (σ_s/σ_t)·z_t) / (α_s − (σ_s/σ_t)·α_t)`` and the per-window
    ``max(SNR(t), 1)``-weighted (capped at 1e4) free-entry mean of ``(x̂ − x̃)²``."""

    def v_hat(cd, z, t):
        return cd[0] * z + cd[1] * t[:, None, None]

    def ddim(z, t, s):
        a_t, s_t = _scales_by_hand(t)
        a_s, s_s = _scales_by_hand(s)
        z = torch.where(mask, x0, z)
        v = v_hat(teacher_cd, z, t)
        x_hat = torch.where(mask, x0, a_t * z - s_t * v)
        eps_hat = s_t * z + a_t * v
        return torch.where(mask, x0, a_s * x_hat + s_s * eps_hat)

    t, mid, s = i / k, (i - 0.5) / k, (i - 1) / k
    alpha_t, sigma_t = _scales_by_hand(t)
    alpha_s, sigma_s = _scales_by_hand(s)
    z = torch.where(mask, x0, alpha_t * x0 + sigma_t * eps)
    z_s = ddim(ddim(z, t, mid), mid, s)
    ratio = sigma_s / sigma_t
    target = torch.where(mask, x0, (z_s - ratio * z) / (alpha_s - ratio * alpha_t))
    x_hat = torch.where(mask, x0, alpha_t * z - sigma_t * v_hat(student_cd, z, t))
    weight = (alpha_t**2 / sigma_t**2).clamp(1.0, 1e4)
    loss = _masked_mean_by_hand(weight * (x_hat - target) ** 2, mask)
    gap = _masked_mean_by_hand((x_hat - target) ** 2, mask).mean()
    return loss, gap


@pytest.fixture
def float64_default():
    """Double precision throughout (the 1e4 cap is checked to 1e-4 relative)."""
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(previous)


@pytest.mark.parametrize(("student_steps", "batch"), [(1, 6), (2, 8), (256, 1024)])
def test_the_loss_is_the_truncated_snr_weighted_error_to_the_two_step_target_by_hand(
    student_steps, batch, make_layout, float64_default
):
    """``i ~ U{1..K}`` and ``ε`` per window, both known entries and free-entry counts
    varied (one window with a single free entry, one with none). ``K = 256`` reaches
    ``SNR(1/256) ≈ 2.7e4``, above the 1e4 cap; ``t = 1`` has ``SNR = 0``, below the floor 1."""
    layout = make_layout()
    teacher = TrajectoryDiffusion(layout, _LinearV(0.8, -0.3), num_steps=2 * student_steps)
    student = TrajectoryDiffusion(layout, _LinearV(0.2, 0.4), num_steps=student_steps)
    identity_statistics(student.normalizer)
    gen = torch.Generator().manual_seed(4)
    observation = torch.randn(batch, layout.length, layout.obs_dim, generator=gen)
    action = torch.randn(batch, layout.length, layout.action_dim, generator=gen)
    mask = torch.rand(batch, *layout.window_shape, generator=gen) < 0.4
    mask |= layout.condition_mask("s0")
    mask[0] = True
    mask[0, 2, 4] = False
    mask[1] = True
    windows = TensorDict(
        {"observation": observation, "action": action, "condition_mask": mask},
        [batch, layout.length],
    )
    x0 = torch.cat([observation, action], -1)  # identity statistics
    torch.manual_seed(8)
    i = torch.randint(1, student_steps + 1, (batch,)).double()
    eps = torch.randn(batch, *layout.window_shape)
    expected, gap = _distillation_by_hand(x0, mask, i, eps, student_steps, (0.8, -0.3), (0.2, 0.4))
    assert (i == student_steps).any()  # t = 1 drawn
    if student_steps == 256:
        assert (i == 1).any()  # the capped SNR drawn

    torch.manual_seed(8)
    out = DistillationLoss(student, teacher, reduction="none")(windows)
    assert out["loss_distillation"].shape == (batch,)
    torch.testing.assert_close(out["loss_distillation"].detach(), expected, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(out["target_gap"], gap, rtol=1e-9, atol=1e-12)


def test_random_draws_follow_the_data_device_not_torch_s_default_device(
    make_layout, make_windows, draws_follow_the_data
):
    """The grid index ``i``, ``ε`` and the ``a_0``-known draw are made where the windows
    live."""
    layout = make_layout()
    teacher = TrajectoryDiffusion(layout, _LinearV(0.8, -0.3), num_steps=4)
    student = TrajectoryDiffusion(layout, _LinearV(0.2, 0.4), num_steps=2)
    identity_statistics(student.normalizer)
    loss_fn = DistillationLoss(student, teacher)
    draws_follow_the_data(loss_fn, make_windows(layout), ("loss_distillation", "target_gap"))
