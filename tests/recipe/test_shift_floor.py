"""``exploration.shift_floor``: DUAL's noise adds ``λ max(d_t − d_0, 0)`` (beyond the
paper's Eq. 10, whose ``d_0`` is 0); ``offline`` measures ``d_0`` as the transition
model's mean error on D_offline after the offline stages; checkpointed with the run.
``exploration.extra_variance``: the constant ``v_c`` added to the variance."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR
from torchrl_dual.recipe import ConfigError, DualLearner, O2ORun, compose_checked, run

pytestmark = pytest.mark.long_running(seconds=30)
SHORT = (
    "budget=smoke",
    "budget.planner_updates=10",
    "budget.distill_updates=[2,2,2,2,2]",
    "budget.offline_updates=10",
    "budget.online_frames=100",
    "budget.frames_per_batch=50",
    "budget.eval_every=100",
    "budget.eval_episodes=1",
    "budget.checkpoint_every=50",
    "env.max_episode_steps=40",
    "progress=false",
    "num_threads=1",
)


def cfg_for(out: Path, cache: Path, *overrides: str):
    args = [*SHORT, f"output_dir={out}", f"data_cache_dir={cache}", *overrides]
    return compose_checked(RECIPE_CONFIG_DIR, args)


def test_offline_floor_is_the_transition_models_mean_error_on_the_data(tmp_path):
    cfg = cfg_for(tmp_path / "run", tmp_path / "data", "exploration.shift_floor=offline")
    learner = O2ORun(cfg, DualLearner).learner
    assert float(learner.noise.shift_floor) == 0.0  # until the stage runs
    learner.pretrain_planner()
    learner.distill()
    learner.set_shift_floor()
    data = learner.run.data.transitions
    gen = torch.Generator().manual_seed(int(cfg.seed))
    batch = data[torch.randperm(len(data), generator=gen)[:20000]]
    with torch.no_grad():
        predicted = learner.transition.predict(batch["observation"], batch["action"])
    by_hand = (predicted - batch["next", "observation"]).norm(dim=-1).mean()
    assert float(learner.noise.shift_floor) == pytest.approx(float(by_hand), rel=1e-6)
    assert float(by_hand) > 0
    # a number is taken as it is; the learner's state carries the floor
    other = O2ORun(cfg_for(tmp_path / "b", tmp_path / "data", "exploration.shift_floor=0.3"),
                   DualLearner).learner  # fmt: skip
    other.set_shift_floor()
    assert float(other.noise.shift_floor) == pytest.approx(0.3)
    learner.load_state_dict(other.state_dict())
    assert float(learner.noise.shift_floor) == pytest.approx(0.3)


def test_a_resumed_run_acts_with_the_floor_of_its_checkpoint(tmp_path):
    overrides = ("exploration.shift_floor=offline",)
    first = run(cfg_for(tmp_path / "run", tmp_path / "data", *overrides, "interrupt_at_frames=50"))
    floor = float(first.learner.noise.shift_floor)
    assert floor > 0 and "shift_floor" in first.stages_done
    resumed = run(cfg_for(tmp_path / "run", tmp_path / "data", *overrides, "resume=true"))
    assert resumed.frames == 100
    assert float(resumed.learner.noise.shift_floor) == floor  # not recomputed, not 0
    # the default is Eq. 10 itself
    plain = O2ORun(cfg_for(tmp_path / "plain", tmp_path / "data"), DualLearner).learner
    plain.set_shift_floor()
    assert float(plain.noise.shift_floor) == 0.0


@pytest.mark.parametrize("value", ["-0.1", "mean"])
def test_a_bad_floor_is_a_config_error(value, tmp_path):
    with pytest.raises(ConfigError, match=r"exploration.shift_floor.*'offline' or a number >= 0"):
        cfg_for(tmp_path, tmp_path, f"exploration.shift_floor={value}")


def test_extra_variance_reaches_the_acting_noise_and_is_an_online_key(tmp_path):
    """``exploration.extra_variance`` sets the acting noise's ``v_c`` (0 by default: Eq. 10)
    and, like λ, is read online only: runs that differ in it share one offline phase."""
    from torchrl_dual.recipe.o2o.offline_cache import offline_key_config

    cfg = cfg_for(tmp_path / "run", tmp_path / "data", "exploration.shift_weight=0",
                  "exploration.extra_variance=0.15")  # fmt: skip
    run = O2ORun(cfg, DualLearner)
    assert run.learner.noise.extra_variance == pytest.approx(0.15)
    assert float(run.learner.noise.shift_weight) == 0.0
    plain = O2ORun(cfg_for(tmp_path / "plain", tmp_path / "data"), DualLearner)
    assert plain.learner.noise.extra_variance == 0.0
    online = DualLearner.online_keys
    assert offline_key_config(run.config, online) == offline_key_config(plain.config, online)
    with pytest.raises(ConfigError, match=r"exploration.extra_variance"):
        cfg_for(tmp_path, tmp_path, "exploration.extra_variance=-0.1")
