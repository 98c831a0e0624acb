"""Tests of ``LaplaceRefits`` (``torchrl_dual/recipe/parts/laplace_refits.py``): the refit
schedule of a learner acting with a Laplace ensemble, on a stand-in base learner, and
its fit (``σ̄``, then Eq. 8 with the learner's weights) on a tiny MLP ensemble."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict
from torchrl.modules import MLP

from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor
from torchrl_dual.recipe.o2o.run import Learner
from torchrl_dual.recipe.parts.laplace_refits import LaplaceRefits


class _Base(Learner):
    """A learner with one offline stage, counted updates and a counter of its own."""

    def __init__(self, refit_every: int) -> None:
        self.run = SimpleNamespace(
            settings=SimpleNamespace(budget=SimpleNamespace(laplace_refit_every=refit_every))
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


def _update(learner: Learner) -> dict:
    """As ``O2ORun.update`` calls a learner: the update, then its ``after_update``."""
    metrics = learner.update(None)
    learner.after_update()
    return metrics


def test_the_laplace_stage_follows_the_base_stages_and_resets_the_count():
    learner = _Refitted(refit_every=3)
    stages = learner.offline_stages()
    assert [name for name, _ in stages] == ["actor_critic", "laplace"]
    learner.refits.since = 5
    stages[1][1]()
    assert (learner.fits, learner.refits.since) == (1, 0)


@pytest.mark.parametrize("block", [1, 2, 3, 5])
def test_refits_once_refit_every_updates_have_accumulated_after_a_block(block):
    learner = _Refitted(refit_every=3)
    for _ in range(6):  # six blocks of `block` updates, the hook after each
        assert all(_update(learner) == {"loss": 1.0} for _ in range(block))
        learner.after_updates()
    assert learner.updates == 6 * block  # the base learner's update ran every time
    blocks_per_fit = -(-3 // block)  # ceil(3 / block)
    assert learner.fits == 6 // blocks_per_fit
    assert learner.refits.since == (6 % blocks_per_fit) * block


def test_the_count_is_checkpointed_with_the_base_state_and_metrics_add_epistemic_std():
    learner = _Refitted(refit_every=10)
    for _ in range(4):
        _update(learner)
    state = learner.state_dict()
    assert state == {"updates": 4, "updates_since_refit": 4}
    fresh = _Refitted(refit_every=10)
    fresh.load_state_dict(state)
    assert (fresh.updates, fresh.refits.since) == (4, 4)
    batch = TensorDict(epistemic_variance=torch.full((5, 2), 0.25), batch_size=[5])
    assert learner.batch_metrics(batch) == {"base": 2.0, "epistemic_std": 0.5}


# ----------------------------------------------------------------------------- the fit
class _Fitted(LaplaceRefits, _Base):
    """The default fit on a tiny MLP ensemble, ``σ̄`` from :meth:`noise_std`."""

    def __init__(self, std: torch.Tensor | None, num_samples: int = 4) -> None:
        super().__init__(refit_every=1)
        torch.manual_seed(0)
        self.ensemble = LaplaceEnsembleActor(
            LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2),
            num_samples=num_samples,
        )
        gen = torch.Generator().manual_seed(1)
        self.data = TensorDict(observation=torch.randn(200, 3, generator=gen), batch_size=[200])
        self.logged: dict = {}
        self.run.all_transitions = lambda: iter([self.data[:120], self.data[120:]])
        self.run.log = lambda values, step, prefix: self.logged.update(values)
        self.run.updates = 7
        self.laplace_weight_fn = lambda batch: batch["observation"][:, 0].exp()
        self.std = std

    def noise_std(self):
        return self.std


def test_the_fit_sets_sigma_bar_then_fits_eq_8_with_the_learner_s_weights():
    learner = _Fitted(torch.tensor([0.2, 5.0]))
    learner.fit_laplace()
    actor = learner.ensemble.actor
    torch.testing.assert_close(actor.std, torch.tensor([0.2, 2.0]))  # clamped to max_std
    reference = LaplaceEnsembleActor(actor, num_samples=4)
    reference.fit_laplace([learner.data], weight_fn=learner.laplace_weight_fn)
    for name in ("G_raw", "theta_map", "noise_variance", "prior_precision"):
        torch.testing.assert_close(
            getattr(learner.ensemble.laplace, name), getattr(reference.laplace, name)
        )
    assert learner.logged.keys() == {"noise_std", "prior_precision"}
    assert learner.logged["noise_std"] == pytest.approx(1.1)


def test_without_a_noise_std_or_samples_the_fit_keeps_sigma_bar_and_skips_the_posterior():
    learner = _Fitted(None)
    learner.fit_laplace()
    torch.testing.assert_close(learner.ensemble.actor.std, torch.full((2,), 0.3))
    assert learner.logged.keys() == {"prior_precision"}
    no_uq = _Fitted(torch.tensor([0.5, 0.5]), num_samples=0)
    no_uq.fit_laplace()
    assert not bool(no_uq.ensemble.laplace.fitted) and no_uq.logged.keys() == {"noise_std"}
