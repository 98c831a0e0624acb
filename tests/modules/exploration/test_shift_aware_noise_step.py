"""``ShiftAwareNoise.step``: TorchRL's exploration-module protocol (issue 30 item 6)."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual import ShiftAwareNoise


def test_step_leaves_the_module_and_its_draws_unchanged():
    """A sota loop calls ``policy[-1].step(frames)`` after each batch; λ is Eq. 10's
    constant, so the state and the next draw are those without the call."""
    noise = ShiftAwareNoise(shift_weight=0.5)
    before = {k: v.clone() for k, v in noise.state_dict().items()}
    td = TensorDict(
        observation=torch.ones(4, 2), loc=torch.zeros(4, 2), scale=torch.ones(4, 2),
        expected_observation=torch.zeros(4, 2), batch_size=[4],
    )  # fmt: skip
    with set_exploration_type(ExplorationType.RANDOM):
        torch.manual_seed(0)
        expected = noise(td.clone())["action"]
        noise.step(500)
        torch.manual_seed(0)
        got = noise(td.clone())["action"]
    torch.testing.assert_close(got, expected)
    assert all(torch.equal(before[k], v) for k, v in noise.state_dict().items())


def test_median_is_the_mean_action_as_deterministic_is():
    noise = ShiftAwareNoise(shift_weight=0.5)
    td = TensorDict({"loc": torch.randn(3, 2), "scale": torch.ones(3, 2)}, [3])
    with set_exploration_type(ExplorationType.MEDIAN):
        out = noise(td.clone())
    torch.testing.assert_close(out["action"], td["loc"])
