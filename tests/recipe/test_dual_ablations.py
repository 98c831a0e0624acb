"""DUAL's ablations as config switches of ``algo=dual`` (paper, Sec. 5 "Ablation studies").

* ``actor.init=scratch``: "w/o planner", the one-step actor keeps its fresh weights;
* ``distillation.final_steps=8``: "w/o distillation", the actor is the 8-step planner;
* ``laplace.uq=latent``: "Ours w τ^N sampling", M planner latents instead of the posterior.

Smoke runs of the switches (``recipes/o2o.py`` as a subprocess, shortened budgets; two
runs for three switches, to keep the file short), in-process checks of what each switch
does to the networks, and the config errors.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from recipe_runner import run_recipe
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules import LaplaceEnsembleActor, PlannerSampler
from torchrl_dual.modules.laplace import LatentEnsembleActor
from torchrl_dual.recipe import CONFIG_DIR, ConfigError, DualLearner, O2ORun, compose_checked

pytestmark = pytest.mark.long_running(seconds=40)  # starts first under xdist
# the smoke budget cut further: these runs check the plumbing of each switch
SHORT = (
    "budget.planner_updates=10",
    "budget.offline_updates=10",
    "budget.online_frames=100",
    "budget.eval_every=100",
    "budget.eval_episodes=2",
)
TINY_DISTILLATION = "budget.distill_updates=[2,2,2,2,2]"


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("data_cache")


def smoke_cfg(output_dir: Path, cache_dir: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [
            "budget=smoke",
            "env=frozenlake",
            f"output_dir={output_dir}",
            f"data_cache_dir={cache_dir}",
            "progress=false",
            "num_threads=1",
            "budget.planner_updates=10",
            TINY_DISTILLATION,
            *overrides,
        ],
    )


def distilled_learner(tmp_path: Path, cache_dir: Path, *overrides: str) -> DualLearner:
    """A learner after its planner and distillation stages (Alg. 1 lines 3-5)."""
    learner = O2ORun(smoke_cfg(tmp_path / "run", cache_dir, *overrides), DualLearner).learner
    learner.pretrain_planner()
    learner.distill()
    return learner


def state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in module.state_dict().items()}


# ----------------------------------------------------------------------------- end to end
@pytest.mark.parametrize(
    "overrides",
    [
        # two switches in one run (they combine; the in-process tests below check each)
        pytest.param(
            ("actor.init=scratch", "laplace.uq=latent", TINY_DISTILLATION),
            id="no-planner+latent-uq",
        ),
        pytest.param(
            ("distillation.final_steps=8", "budget.distill_updates=[2,2]"), id="no-distillation"
        ),
    ],
)
def test_each_ablation_runs_end_to_end(overrides, tmp_path, cache_dir):
    proc = run_recipe(tmp_path / "run", cache_dir, *SHORT, *overrides)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-4000:]}"
    assert "normalized score at the end of the online phase:" in proc.stdout


# ----------------------------------------------------------------------------- what they change
def test_a_scratch_actor_keeps_its_fresh_weights_and_the_student_feeds_the_transition_model(
    tmp_path, cache_dir
):
    run = O2ORun(smoke_cfg(tmp_path / "run", cache_dir, "actor.init=scratch"), DualLearner)
    learner = run.learner
    fresh = state(learner.actor.model)
    learner.pretrain_planner()
    learner.distill()
    actor, student = state(learner.actor.model), state(learner.transition.model)
    assert all(torch.equal(actor[k], fresh[k]) for k in fresh)  # not initialised from g_θ'
    weights = [f"denoiser.{name}" for name, _ in learner.actor.model.denoiser.named_parameters()]
    assert all(not torch.equal(actor[k], student[k]) for k in weights)  # the student differs
    # the normalizer is the planner's, fitted on D_offline (not the identity), in both
    for k in ("normalizer.action_mean", "normalizer.obs_std"):
        torch.testing.assert_close(actor[k], student[k])
    assert not torch.allclose(
        actor["normalizer.obs_std"], torch.ones_like(actor["normalizer.obs_std"])
    )


def test_a_distilled_actor_starts_from_the_student(tmp_path, cache_dir):
    learner = distilled_learner(tmp_path, cache_dir)
    actor, student = state(learner.actor.model), state(learner.transition.model)
    assert all(torch.equal(actor[k], student[k]) for k in actor)


def test_without_distillation_the_actor_is_the_8_step_student(tmp_path, cache_dir):
    learner = distilled_learner(
        tmp_path, cache_dir, "distillation.final_steps=8", "budget.distill_updates=[2,2]"
    )
    actor = learner.actor
    assert actor.num_steps == 8 and actor.model.num_steps == 8
    assert learner.transition.model.num_steps == 8
    observation = learner.run.data.transitions["observation"][:16]
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        reference, _ = PlannerSampler(learner.transition.model)(observation)
        mean = actor(observation)
    torch.testing.assert_close(mean, reference, rtol=1e-5, atol=1e-5)
    assert isinstance(learner.ensemble, LaplaceEnsembleActor)


def test_latent_uq_builds_the_latent_ensemble_and_fits_no_posterior(tmp_path, cache_dir):
    learner = O2ORun(
        smoke_cfg(tmp_path / "run", cache_dir, "laplace.uq=latent"), DualLearner
    ).learner
    assert isinstance(learner.ensemble, LatentEnsembleActor)
    assert learner.ensemble.num_samples == learner.settings.laplace.num_samples
    assert not learner.uses_posterior
    learner.fit_laplace()  # a no-op: nothing to fit
    assert "laplace.uq" in DualLearner.online_keys  # the offline phase does not read it


# ----------------------------------------------------------------------------- config errors
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ["distillation.final_steps=8"],
            "budget.distill_updates=[100, 100, 200, 400, 800]: must have 2 entries, one per "
            "halving round of planner.num_steps=32 -> 8 (distillation.final_steps)",
        ),
        (["distillation.final_steps=64"], "must be <= planner.num_steps=32"),
        (["distillation.final_steps=3"], "must be a power of 2"),
        (
            ["actor.init=scratch", "exploration.transition_model=shared"],
            "exploration.transition_model=shared: with actor.init=scratch",
        ),
        (
            ["actor.init=scratch", "distillation.final_steps=8", "budget.distill_updates=[1,1]"],
            "actor.init=scratch: is the one-step actor without the planner prior",
        ),
        (["laplace.uq=latent", "laplace.num_samples=1"], "laplace.num_samples=1: must be >= 2"),
        (["laplace.uq=latent", "planner.schedule=linear"], "laplace.uq=latent: needs planner"),
        (["laplace.uq=bayes"], "laplace.uq=bayes: unknown option; choose one of laplace, latent"),
        (["actor.init=zero"], "actor.init=zero: unknown option; choose one of distilled, scratch"),
    ],
)
def test_bad_combinations_name_the_key_at_fault(overrides, message):
    with pytest.raises(ConfigError) as err:
        compose_checked(CONFIG_DIR, overrides)
    assert message in str(err.value)


@pytest.mark.parametrize("algo", ["dual", "iql_la", "diffql_la"])
def test_posterior_temperature_reaches_the_acting_posterior(algo, tmp_path):
    """``laplace.posterior_temperature`` is the ``temperature`` of the ensemble's
    ``LastLayerLaplace`` for every algorithm that acts with one (issue 29)."""
    from torchrl_dual.recipe import ALGORITHMS

    for value, expected in (("data", "data"), ("4.0", 4.0)):
        cfg = compose_checked(
            CONFIG_DIR,
            [f"algo={algo}", "budget=smoke", "env=frozenlake", f"output_dir={tmp_path / value}",
             f"laplace.posterior_temperature={value}", "progress=false", "num_threads=1",
             "budget.dataset_transitions=1000"],
        )  # fmt: skip
        learner = O2ORun(cfg, ALGORITHMS[algo].learner).learner
        assert learner.ensemble.laplace.temperature == expected
