"""Tests of ``DistillationLoss`` (``torchrl_dual/objectives/distillation.py``) and the
``progressive_distillation`` driver (``torchrl_dual/training.py``)."""

from __future__ import annotations

import copy
import statistics

import pytest
import torch

from torchrl_dual.objectives import DistillationLoss
from torchrl_dual.objectives import progressive_distillation

pytestmark = pytest.mark.usefixtures("seeded")


def _pair(make_model, teacher_steps=4, **kwargs):
    teacher = make_model(num_steps=teacher_steps, **kwargs)
    student = copy.deepcopy(teacher)
    student.num_steps = teacher_steps // 2
    return student, teacher


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
        ValueError, match=rf"teacher has 4, student {student_steps}; set student.num_steps = 2"
    ):
        DistillationLoss(student, teacher)


def test_the_teacher_itself_cannot_be_the_student(make_model):
    model = make_model(num_steps=2)
    with pytest.raises(ValueError, match="teacher has 2, student 2"):
        DistillationLoss(model, model)


def test_only_the_student_receives_gradients_and_updates(make_model, make_windows):
    student, teacher = _pair(make_model)
    loss_fn = DistillationLoss(student, teacher)
    loss_params = {id(p) for p in loss_fn.parameters()}
    assert loss_params == {id(p) for p in student.parameters()}
    assert not loss_params & {id(p) for p in teacher.parameters()}
    teacher_state, teacher_buffers = _state(teacher), loss_fn.teacher_buffers.clone()
    student_state = _state(student)
    optimizer = torch.optim.Adam(loss_fn.parameters(), lr=1e-2)

    loss_fn(make_windows())["loss_distillation"].backward()
    for name, param in student.denoiser.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, name
    assert all(p.grad is None for p in teacher.parameters())
    assert all(t.grad is None for t in loss_fn.teacher_buffers.values(True, True))
    optimizer.step()

    _assert_same_state(teacher, teacher_state)
    assert (loss_fn.teacher_buffers == teacher_buffers).all()
    changed = [k for k, v in student.state_dict().items() if not torch.equal(v, student_state[k])]
    assert any(k.startswith("denoiser.") for k in changed)


def test_the_frozen_teacher_weights_never_require_grad(make_model, make_windows):
    loss_fn = DistillationLoss(*_pair(make_model))
    assert not any(t.requires_grad for t in loss_fn.teacher_buffers.values(True, True))
    loss_fn(make_windows())
    assert not any(t.requires_grad for t in loss_fn.teacher_buffers.values(True, True))


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
    with pytest.raises(KeyError, match=r"no observation entry 'observation'"):
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


def test_reduction_none_returns_one_loss_per_window(make_model, make_windows):
    loss_fn = DistillationLoss(*_pair(make_model), reduction="none")
    assert loss_fn(make_windows(batch=6))["loss_distillation"].shape == (6,)


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
    rounds = list(dict.fromkeys(name.split("/")[0] for name in logger.names))
    assert rounds == ["distill_16", "distill_8", "distill_4", "distill_2", "distill_1"]
    assert not torch.equal(student.denoiser.head.weight, teacher.denoiser.head.weight)
    assert torch.equal(student.normalizer.obs_mean, teacher.normalizer.obs_mean)
    cond, mask = student.layout.conditioned_window(torch.zeros(3, 1))
    assert torch.isfinite(student.sample(cond, mask)).all()


def test_progressive_distillation_stops_at_final_steps(make_toy_setup):
    teacher, buffer = make_toy_setup(num_steps=8)
    student = progressive_distillation(teacher, buffer.sample, 1, final_steps=2, progress=False)
    assert student.num_steps == 2


@pytest.mark.parametrize("final_steps", [0, 3, 16])
def test_progressive_distillation_rejects_a_final_steps_not_n_over_a_power_of_two(
    final_steps, make_model
):
    with pytest.raises(ValueError, match=rf"final_steps={final_steps} must be N / 2\^k"):
        progressive_distillation(make_model(num_steps=8), lambda: None, 1, final_steps=final_steps)
