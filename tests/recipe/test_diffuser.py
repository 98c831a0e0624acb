"""The ``diffuser`` baseline (``torchrl_dual/recipe/algos/diffuser.py``): the undistilled
N-step planner acting with ``τ_{a_0}``, ``L_VLB`` offline and on ``D_offline ∪ D_online``."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from recipe_runner import run_recipe, succeeded
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules import PlannerSampler
from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR
from torchrl_dual.recipe import O2ORun, compose_checked
from torchrl_dual.recipe.algos.diffuser import DiffuserLearner


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("data_cache")


def learner(tmp_path: Path, cache_dir: Path, *overrides: str) -> DiffuserLearner:
    cfg = compose_checked(
        RECIPE_CONFIG_DIR,
        [
            "algo=diffuser",
            "budget=smoke",
            "env=frozenlake",
            f"output_dir={tmp_path / 'run'}",
            f"data_cache_dir={cache_dir}",
            "progress=false",
            "num_threads=1",
            *overrides,
        ],
    )
    return O2ORun(cfg, DiffuserLearner).learner


def test_it_runs_end_to_end_on_frozen_lake(tmp_path, cache_dir):
    proc = succeeded(
        run_recipe(
            tmp_path / "run",
            cache_dir,
            "algo=diffuser",
            "env=frozenlake",
            "budget.planner_updates=10",
            "budget.online_frames=200",
            "budget.eval_every=200",
            "budget.eval_episodes=2",
        )
    )
    assert "normalized score at the end of the online phase:" in proc.stdout


def test_it_acts_with_the_n_step_plan_first_action(tmp_path, cache_dir):
    diffuser = learner(tmp_path, cache_dir)
    planner = diffuser.planner
    assert planner.num_steps == 32  # the teacher itself: no distillation
    observation = diffuser.run.data.transitions["observation"][:8]
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = diffuser.evaluation_policy(TensorDict(observation=observation, batch_size=[8]))
        reference, _ = PlannerSampler(planner)(observation)
    space = diffuser.run.env.action_spec.space
    torch.testing.assert_close(td["action"], reference.clamp(space.low, space.high))


def test_updates_lower_l_vlb_and_mix_in_online_windows(tmp_path, cache_dir):
    diffuser = learner(tmp_path, cache_dir, "budget.batch_size=32")
    fixed = diffuser.offline_windows.sample()

    def vlb() -> float:
        torch.manual_seed(0)  # the same t and ε draws each time
        with torch.no_grad():
            return float(diffuser.loss(fixed)["loss_diffusion"])

    before = vlb()
    for _ in range(30):
        diffuser.update(None)
    assert vlb() < before
    # D_online: two 10-step episodes with a recognisable observation
    online = diffuser.run.data.transitions[:20].clone()
    online["observation"].fill_(100.0)
    online["episode"] = torch.arange(20) // 10 + 10_000
    diffuser.run.replay.extend(online)
    windows = diffuser.windows()
    assert windows.shape[0] == 32 and diffuser.online_windows is not None
    from_online = (windows["observation"] == 100.0).all(-1).all(-1)
    assert int(from_online.sum()) == 32 - round(diffuser.settings.online.offline_fraction * 32)
