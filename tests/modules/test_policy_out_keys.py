"""DUAL's policies write exactly their ``out_keys`` in every exploration mode (TorchRL's
collectors and specs rely on it; issue 30 item 6)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_compile import _policies, _step  # noqa: E402


@pytest.mark.parametrize("name", ["dual", "iql_la"])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_each_module_writes_exactly_its_out_keys(name, mode):
    policy = _policies()[name]
    step = _step()
    with torch.no_grad(), set_exploration_type(mode):
        for module in (policy[0], policy):
            written = set(module(step.clone()).keys(True, True)) - set(step.keys(True, True))
            assert written == set(module.out_keys), (type(module).__name__, written)


def test_the_deterministic_step_has_no_shift_and_no_noise():
    policy = _policies()["dual"]
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        out = policy(_step())
    torch.testing.assert_close(out["expected_observation"], out["observation"])
    assert (out["shift_distance"] == 0).all() and (out["exploration_scale"] == 0).all()
    torch.testing.assert_close(out["action"], out["loc"].clamp(-1, 1))


@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_get_dist_is_the_gaussian_of_eq_9(mode):
    ensemble = _policies()["dual"][0]
    step = _step()
    with torch.no_grad(), set_exploration_type(mode):
        out = ensemble(step.clone())
        dist = ensemble.get_dist(step)
    assert set(step.keys()) == {"observation", "previous_observation", "previous_action",
                                "previous_valid"}  # fmt: skip
    torch.testing.assert_close(dist.mean, out["loc"])
    torch.testing.assert_close(dist.stddev, out["scale"])
    reference = torch.distributions.Normal(out["loc"], out["scale"])
    torch.testing.assert_close(
        dist.log_prob(out["action"]), reference.log_prob(out["action"]).sum(-1)
    )
