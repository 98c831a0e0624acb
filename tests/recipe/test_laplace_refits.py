"""Tests of ``LaplaceRefits`` (``torchrl_dual/recipe/laplace_refits.py``): the refit
schedule of a learner acting with a Laplace ensemble, on a stand-in base learner."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict

from torchrl_dual.recipe.laplace_refits import LaplaceRefits
from torchrl_dual.recipe.o2o_run import Learner


class _Base(Learner):
    """A learner with one offline stage, counted updates and a counter of its own."""

    def __init__(self, refit_every: int) -> None:
        self.run = SimpleNamespace(
            cfg=SimpleNamespace(budget=SimpleNamespace(laplace_refit_every=refit_every))
        )
        self.updates, self.fits = 0, 0

    def modules(self) -> dict:
        return {}

    def offline_stages(self) -> list:
        return [("actor_critic", lambda: None)]

    def update(self, batch) -> dict:
        self.updates += 1
        return {"loss": 1.0}

    def batch_metrics(self, batch) -> dict:
        return {"base": 2.0}

    def state_dict(self) -> dict:
        return {"updates": self.updates}

    def load_state_dict(self, state: dict) -> None:
        self.updates = state["updates"]


class _Refitted(LaplaceRefits, _Base):
    def fit_laplace(self) -> None:
        self.fits += 1


def test_the_laplace_stage_follows_the_base_stages_and_resets_the_count():
    learner = _Refitted(refit_every=3)
    stages = learner.offline_stages()
    assert [name for name, _ in stages] == ["actor_critic", "laplace"]
    learner.updates_since_refit = 5
    stages[1][1]()
    assert (learner.fits, learner.updates_since_refit) == (1, 0)


@pytest.mark.parametrize("block", [1, 2, 3, 5])
def test_refits_once_refit_every_updates_have_accumulated_after_a_block(block):
    learner = _Refitted(refit_every=3)
    for _ in range(6):  # six blocks of `block` updates, the hook after each
        assert all(learner.update(None) == {"loss": 1.0} for _ in range(block))
        learner.after_updates()
    assert learner.updates == 6 * block  # the base learner's update ran every time
    blocks_per_fit = -(-3 // block)  # ceil(3 / block)
    assert learner.fits == 6 // blocks_per_fit
    assert learner.updates_since_refit == (6 % blocks_per_fit) * block


def test_the_count_is_checkpointed_with_the_base_state_and_metrics_add_epistemic_std():
    learner = _Refitted(refit_every=10)
    for _ in range(4):
        learner.update(None)
    state = learner.state_dict()
    assert state == {"updates": 4, "updates_since_refit": 4}
    fresh = _Refitted(refit_every=10)
    fresh.load_state_dict(state)
    assert (fresh.updates, fresh.updates_since_refit) == (4, 4)
    batch = TensorDict(epistemic_variance=torch.full((5, 2), 0.25), batch_size=[5])
    assert learner.batch_metrics(batch) == {"base": 2.0, "epistemic_std": 0.5}
