"""Planner augmentation (``torchrl_dual/recipe/parts/planner_augment.py``): ``algo=edis`` and
``algo=dual augment.kind=planner``, end to end at a cut-down smoke budget, in process.

The online phase is 100 frames in 2 blocks of 50, each followed by 10 updates; with
``augment.every=10`` (``budget.laplace_refit_every``) a round runs after each block and
adds ``augment.num_windows=8`` windows of ``H = 8`` transitions to ``D_online``. The edis
run is interrupted after the first block and resumed.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from test_diffql import CONFIG_DIR, POINTMAZE, checkpoint_state
from test_diffql import FAST as CUT_SMOKE_BUDGET

from torchrl_dual.recipe import O2ORun, compose_checked, run
from torchrl_dual.recipe.algos.dual import DualLearner
from torchrl_dual.recipe.algos.edis import EDISLearner
from torchrl_dual.recipe.parts.planner_augment import is_generated

FAST = [
    "budget=smoke",
    "progress=false",
    "num_threads=1",
    *POINTMAZE,
    "budget.planner_updates=20",
    *CUT_SMOKE_BUDGET,
    "augment.num_windows=8",
    "augment.guider_updates=5",
    "augment.reward_updates=5",
]
WINDOWS, HORIZON = 8, 8


def run_in_process(output_dir: Path, cache_dir: Path, *overrides: str):
    cfg = compose_checked(
        CONFIG_DIR, [*FAST, f"output_dir={output_dir}", f"data_cache_dir={cache_dir}", *overrides]
    )
    return run(cfg)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("edis_data")


@pytest.fixture(scope="module")
def edis_run(tmp_path_factory, cache_dir):
    """``algo=edis`` stopped after 50 frames, its checkpoint state, then resumed."""
    out = tmp_path_factory.mktemp("edis")
    run_in_process(out, cache_dir, "algo=edis", "interrupt_at_frames=50")
    interrupted = checkpoint_state(out)
    return out, interrupted, run_in_process(out, cache_dir, "algo=edis", "resume=true")


def generated_part(result) -> tuple:
    online = result.replay.online_buffer
    data = online[: len(online)]
    mask = is_generated(data)
    return data[~mask], data[mask]


def test_edis_runs_the_planner_stage_then_iql_and_resumes_the_augmentation(edis_run):
    out, interrupted, result = edis_run
    assert isinstance(result.learner, EDISLearner)
    assert interrupted["learner"]["augment"] == {"rounds_done": 1, "generated_windows": WINDOWS}
    state = checkpoint_state(out)
    assert state["stages_done"] == ["planner", "actor_critic", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 10 + 20)
    assert state["learner"]["augment"] == {"rounds_done": 2, "generated_windows": 2 * WINDOWS}
    assert {"planner", "augment_guider", "augment_reward", "augment_guider_optimizer"} <= set(state)
    # one id per window, never reused across the resume: the counters were restored
    real, generated = generated_part(result)
    assert set(generated["episode"].tolist()) == set(range(-2 * WINDOWS, 0))
    assert real.shape[0] == 100 and (real["episode"] >= 0).all()
    # room for every round's transitions next to the collected frames
    assert result.replay.online_buffer.storage.max_size == 100 + 2 * WINDOWS * HORIZON
    rounds = out / "logs" / "edis" / "scalars" / "augment" / "transitions.csv"
    assert len(rounds.read_text().splitlines()) == 2


def test_generated_transitions_have_the_collected_layout_and_chain_inside_a_window(edis_run):
    _, _, result = edis_run
    real, generated = generated_part(result)
    assert 2 * WINDOWS <= generated.shape[0] <= 2 * WINDOWS * HORIZON
    assert set(generated.keys(True, True)) == set(real.keys(True, True))
    for key in real.keys(True, True):
        assert generated[key].dtype == real[key].dtype, key
        assert generated[key].shape[1:] == real[key].shape[1:], key
    space = result.env.action_spec.space
    assert ((generated["action"] >= space.low) & (generated["action"] <= space.high)).all()
    assert torch.equal(generated["next", "done"], generated["next", "terminated"])
    assert not generated["next", "truncated"].any()
    same_window = generated["episode"][1:] == generated["episode"][:-1]
    assert same_window.sum() > 0
    assert torch.equal(
        generated["next", "observation"][:-1][same_window],
        generated["observation"][1:][same_window],
    )
    # the last round's labels are the final reward model's
    last = generated[generated["episode"] < -WINDOWS]
    reward, terminated = result.learner.augmenter.reward_model.predict(
        last["observation"], last["action"], last["next", "observation"]
    )
    assert torch.equal(reward, last["next", "reward"])
    assert torch.equal(terminated, last["next", "terminated"])


def test_a_window_is_cut_after_its_first_predicted_terminal(edis_run):
    _, _, result = edis_run
    augmenter = result.learner.augmenter
    windows = torch.randn(3, HORIZON + 1, augmenter.layout.transition_dim)
    head = augmenter.reward_model.net[-1]
    with torch.no_grad():
        saved = head.bias.clone()
        head.bias[1] = 1e4  # every transition terminal: one per window is kept
        cut = augmenter.windows_to_transitions(windows, first=100)
        head.bias.copy_(saved)
        head.bias[1] = -1e4  # none terminal: all H per window
        full = augmenter.windows_to_transitions(windows, first=100)
        head.bias.copy_(saved)
    assert cut["episode"].tolist() == [-101, -102, -103]
    assert cut["next", "done"].all()
    assert full.shape[0] == 3 * HORIZON and not full["next", "done"].any()
    obs_dim = augmenter.layout.obs_dim
    assert torch.equal(cut["observation"], windows[:, 0, :obs_dim])


def test_dual_with_planner_augmentation_guides_its_teacher(tmp_path, cache_dir):
    result = run_in_process(tmp_path, cache_dir, "algo=dual", "augment.kind=planner")
    learner = result.learner
    assert isinstance(learner, DualLearner)
    assert learner.augmenter.planner is learner.teacher
    assert learner.augmenter.state_dict() == {"rounds_done": 2, "generated_windows": 2 * WINDOWS}
    _, generated = generated_part(result)
    assert set(generated["episode"].tolist()) == set(range(-2 * WINDOWS, 0))
    state = checkpoint_state(tmp_path)
    assert state["stages_done"] == [
        "planner",
        "distillation",
        "actor_critic",
        "laplace",
        "offline_eval",
    ]
    assert {"augment_guider", "augment_reward"} <= set(state)
    assert state["learner"]["augment"] == learner.augmenter.state_dict()


def test_planner_augmentation_leaves_dual_s_networks_and_random_stream_as_they_were(
    tmp_path, cache_dir
):
    """The augmenter's networks come from their own stream: DUAL's offline phase (and
    with it an offline_cache entry) is the same with and without augmentation."""
    states = []
    for kind in ("none", "planner"):
        overrides = [*FAST, f"output_dir={tmp_path / kind}", f"data_cache_dir={cache_dir}"]
        cfg = compose_checked(CONFIG_DIR, [*overrides, "algo=dual", f"augment.kind={kind}"])
        learner = O2ORun(cfg, DualLearner).learner
        states.append((torch.get_rng_state(), learner.teacher.state_dict()))
    (rng_none, teacher_none), (rng_planner, teacher_planner) = states
    assert torch.equal(rng_none, rng_planner)
    assert all(torch.equal(teacher_none[k], teacher_planner[k]) for k in teacher_none)
