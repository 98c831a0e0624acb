"""A 32-step teacher and its distilled 1-step student on bimodal windows.

The data's windows go left (30 %) or right (70 %) from near the origin. The test
checks the issue's criteria: both samplers reproduce the two modes (frequencies within
0.1 of the data's) and the student's mean distance to the nearest true mode stays
within 2x the teacher's, whereas the teacher run with a single step collapses. It takes
about a minute and a half on one CPU core; the figures are printed (``pytest -s``).
"""

from __future__ import annotations

import pytest
import torch
from toy import LEFT_FRACTION, bimodal_transitions, mode_statistics

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout, WindowReplayBuffer
from torchrl_dual.objectives import progressive_distillation, train_planner

pytestmark = pytest.mark.long_running(seconds=175)  # starts first under xdist
HORIZON = 8


def _sample_windows(model: TrajectoryDiffusion, steps: int, n: int = 4000):
    gen = torch.Generator().manual_seed(1)
    observation = 0.1 * torch.randn(n, 1, generator=gen)
    norm = model.normalizer
    cond, mask = model.layout.conditioned_window(norm.normalize_observation(observation))
    with torch.no_grad():
        window = model.sample(cond, mask, num_steps=steps, generator=gen)
    raw = torch.cat(
        [norm.denormalize_observation(window[..., :1]), norm.denormalize_action(window[..., 1:])],
        dim=-1,
    )
    return mode_statistics(raw, observation)


@pytest.fixture(scope="module")
def teacher_and_student():
    with torch.random.fork_rng():
        torch.manual_seed(0)
        data = bimodal_transitions()
        layout = TrajectoryLayout(obs_dim=1, action_dim=1, horizon=HORIZON)
        windows = WindowReplayBuffer(data, HORIZON, batch_size=256)
        teacher = TrajectoryDiffusion(layout, num_steps=32, hidden=128, depth=2)
        teacher.normalizer.fit(data["observation"], data["action"])
        # Only s_0 is ever known in this test, so the planner is trained as a policy.
        train_planner(
            teacher, windows.sample, 2500, lr=1e-3, action_condition_prob=0.0, progress=False
        )
        student = progressive_distillation(
            teacher,
            windows.sample,
            [300, 300, 600, 1500, 4000],
            lr=3e-4,
            action_condition_prob=0.0,
            progress=False,
        )
    return teacher, student


def test_teacher_and_distilled_student_both_reproduce_the_two_modes(teacher_and_student):
    teacher, student = teacher_and_student
    assert student.num_steps == 1 and teacher.num_steps == 32
    left_32, dist_32 = _sample_windows(teacher, 32)
    left_1, dist_1 = _sample_windows(student, 1)
    collapsed_left, collapsed_dist = _sample_windows(teacher, 1)
    print(
        f"\nleft-mode frequency: data {LEFT_FRACTION:.3f}, teacher N=32 {left_32:.3f}, "
        f"student N=1 {left_1:.3f}, teacher N=1 {collapsed_left:.3f}"
        f"\nmean RMS distance to nearest mode: teacher N=32 {dist_32:.4f}, student N=1 "
        f"{dist_1:.4f} ({dist_1 / dist_32:.2f}x), teacher N=1 {collapsed_dist:.4f}"
    )
    assert abs(left_32 - LEFT_FRACTION) <= 0.1
    assert abs(left_1 - LEFT_FRACTION) <= 0.1
    assert dist_1 <= 2.0 * dist_32
    # Without distillation a single step is not enough: the same network loses a mode.
    assert abs(collapsed_left - LEFT_FRACTION) > 0.1 or collapsed_dist > 2.0 * dist_32
