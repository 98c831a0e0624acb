"""Local PointMaze data: D4RL-like episodes, windows inside episodes, references, cache."""

from __future__ import annotations

import pytest
import torch
from torchrl.data import SliceSampler

from torchrl_dual.data import (
    compute_maze_references,
    generate_maze_dataset,
    load_or_generate_maze_dataset,
    to_replay_buffer,
    validate_transitions,
)

STEPS = 100


@pytest.fixture(scope="module")
def data():
    return generate_maze_dataset(
        "umaze", 1050, seed=0, max_episode_steps=STEPS, num_reference_episodes=0
    )


def test_data_follows_the_transition_layout_with_bounded_actions(data):
    validate_transitions(data.transitions, obs_dim=6, action_dim=2)
    assert len(data) == 1050
    assert data.transitions["action"].abs().max() <= 1.0


def test_episodes_are_contiguous_full_length_and_end_truncated(data):
    td = data.transitions
    episode = td["episode"]
    assert torch.equal(episode, torch.arange(1050) // STEPS)
    ends = td["next", "truncated"].squeeze(-1).nonzero().squeeze(-1)
    assert ends.tolist() == [*range(STEPS - 1, 1050, STEPS), 1049]
    assert not td["next", "terminated"].any()


def test_task_goal_is_fixed_within_an_episode_and_redrawn_at_each_reset(data):
    goals = data.transitions["observation"][:, 4:].reshape(-1, 50, 2)[:20]  # 2 rows per episode
    assert torch.equal(goals, goals[:, :1].expand_as(goals))
    assert goals[::2, 0].unique(dim=0).shape[0] > 3


def test_reward_is_the_sparse_task_reward_of_the_next_observation(data):
    nxt = data.transitions["next", "observation"]
    reached = ((nxt[:, :2] - nxt[:, 4:]).norm(dim=-1) <= 0.45).float()
    assert torch.equal(data.transitions["next", "reward"].squeeze(-1), reached)


def test_slice_sampler_windows_never_cross_episodes(data):
    rb = to_replay_buffer(
        data.transitions, sampler=SliceSampler(slice_len=8, traj_key="episode"), batch_size=256
    )
    for _ in range(20):
        batch = rb.sample().reshape(32, 8)
        assert (batch["episode"] == batch["episode"][:, :1]).all()
        torch.testing.assert_close(
            batch["next", "observation"][:, :-1], batch["observation"][:, 1:]
        )


def test_controller_chases_its_own_goals_not_the_task_goal(data):
    assert data.metadata["own_goals_reached"] >= 10
    assert data.metadata["reward_fraction"] < 0.5


def test_same_seed_reproduces_the_data_and_another_seed_changes_it():
    a = generate_maze_dataset("umaze", 200, seed=1, max_episode_steps=50, num_reference_episodes=0)
    b = generate_maze_dataset("umaze", 200, seed=1, max_episode_steps=50, num_reference_episodes=0)
    c = generate_maze_dataset("umaze", 200, seed=2, max_episode_steps=50, num_reference_episodes=0)
    assert (a.transitions == b.transitions).all()
    assert not torch.equal(a.transitions["observation"], c.transitions["observation"])


def test_goal_chasing_controller_beats_the_random_policy():
    refs = compute_maze_references("umaze", num_episodes=4, seed=0, max_episode_steps=200)
    assert refs["controller_success"] == 1.0
    assert refs["controller_return"] > refs["random_return"] + 50


def test_cache_round_trip_and_regeneration_when_arguments_change(tmp_path):
    kwargs = dict(max_episode_steps=50, num_reference_episodes=1)
    first = load_or_generate_maze_dataset("umaze", 120, 0, tmp_path, **kwargs)
    again = load_or_generate_maze_dataset("umaze", 120, 0, tmp_path, **kwargs)
    assert (first.transitions == again.transitions).all()
    assert again.reference_max == first.reference_max > first.reference_min
    assert again.metadata["references"]["controller_success"] == 1.0
    noisier = load_or_generate_maze_dataset("umaze", 120, 0, tmp_path, action_noise=1.0, **kwargs)
    assert noisier.metadata["action_noise"] == 1.0
    assert not torch.equal(noisier.transitions["action"], first.transitions["action"])


def test_unknown_maze_fails_before_generating(tmp_path):
    with pytest.raises(ValueError, match="Valid names"):
        load_or_generate_maze_dataset("spiral", 10, 0, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_goal_cell_fixes_the_data_goal_and_has_its_own_cache_entry(tmp_path):
    """The data's task goal (observation and reward) lies in ``goal_cell`` in every
    episode, the references are computed for it, and the entry sits next to the
    random-goal one instead of replacing it."""
    kwargs = dict(max_episode_steps=50, num_reference_episodes=1, verbose=False)
    free = load_or_generate_maze_dataset("umaze", 200, 0, tmp_path, **kwargs)
    fixed = load_or_generate_maze_dataset("umaze", 200, 0, tmp_path, goal_cell=[3, 1], **kwargs)
    goals = fixed.transitions["observation"][:, 4:]
    # umaze cell (3, 1) is the bottom-left one: x < -0.5, y < -0.5 (cells of size 1)
    assert (goals[:, 0] < -0.5).all() and (goals[:, 1] < -0.5).all()
    assert free.transitions["observation"][:, 4:].unique(dim=0).shape[0] > 1
    assert fixed.metadata["goal_cell"] == [3, 1] and free.metadata["goal_cell"] is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "pointmaze-umaze-goal3_1-n200-seed0",
        "pointmaze-umaze-n200-seed0",
    ]
    again = load_or_generate_maze_dataset("umaze", 200, 0, tmp_path, goal_cell=[3, 1], **kwargs)
    assert torch.equal(again.transitions["observation"], fixed.transitions["observation"])
    with pytest.raises(ValueError, match="not an open cell of the umaze maze"):
        load_or_generate_maze_dataset("umaze", 200, 0, tmp_path, goal_cell=[2, 1], **kwargs)
