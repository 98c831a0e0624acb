"""validate_transitions: every layout violation is reported with its field and a fix."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_dual.data import TRANSITION_KEYS, make_transitions, validate_transitions


def _transitions(lengths=(4, 3), obs_dim=3, act_dim=2):
    n = sum(lengths)
    obs, nxt, episode, trunc = [], [], [], []
    for ep, length in enumerate(lengths):
        states = np.random.default_rng(ep).normal(size=(length + 1, obs_dim))
        obs.append(states[:-1])
        nxt.append(states[1:])
        episode += [ep] * length
        trunc += [False] * (length - 1) + [True]
    return make_transitions(
        np.concatenate(obs),
        np.zeros((n, act_dim)),
        np.concatenate(nxt),
        np.zeros(n),
        np.zeros(n, bool),
        np.array(trunc),
        np.array(episode),
    )


def test_well_formed_transitions_pass_and_are_returned():
    td = _transitions()
    assert validate_transitions(td, obs_dim=3, action_dim=2) is td
    assert set(td.keys(True, True)) == set(TRANSITION_KEYS)


def test_missing_keys_are_all_listed():
    td = _transitions().exclude(("next", "reward"), "episode")
    with pytest.raises(ValueError, match=r"missing the keys \[\('next', 'reward'\), 'episode'\]"):
        validate_transitions(td)


def test_wrong_observation_dim_reports_expected_and_got():
    with pytest.raises(
        ValueError, match="'observation' has size 3 on its last dim, expected obs_dim=6"
    ):
        validate_transitions(_transitions(), obs_dim=6)


def test_wrong_action_dim_reports_expected_and_got():
    with pytest.raises(
        ValueError, match="'action' has size 2 on its last dim, expected action_dim=1"
    ):
        validate_transitions(_transitions(), action_dim=1)


def test_nan_entries_are_reported_with_field_name_and_count():
    td = _transitions()
    td["action"][1, 0] = float("nan")
    td["action"][2] = float("nan")
    with pytest.raises(
        ValueError, match=r"'action' has 3 NaN and 0 inf entries \(first rows: \[1, 2\]\)"
    ):
        validate_transitions(td)


def test_inf_reward_is_reported_with_its_nested_key():
    td = _transitions()
    td["next", "reward"][0] = float("inf")
    with pytest.raises(ValueError, match=r"\('next', 'reward'\) has 0 NaN and 1 inf"):
        validate_transitions(td)


def test_non_contiguous_episodes_are_rejected():
    td = _transitions(lengths=(2, 2, 2))
    td["episode"] = torch.tensor([0, 0, 1, 1, 0, 0])
    with pytest.raises(ValueError, match=r"not contiguous: episode ids \[0\]"):
        validate_transitions(td)


def test_done_in_the_middle_of_an_episode_is_rejected():
    td = _transitions()
    td["next", "terminated"][1] = True
    td["next", "done"][1] = True
    with pytest.raises(ValueError, match=r"done but not the last of their episode \(rows \[1\]\)"):
        validate_transitions(td)


def test_misaligned_next_observation_is_rejected():
    td = _transitions()
    td["next", "observation"][0] += 1.0
    with pytest.raises(ValueError, match=r"different from the following 'observation'.*rows \[0\]"):
        validate_transitions(td)


def test_done_must_equal_terminated_or_truncated():
    td = _transitions()
    td["next", "done"][-1] = False
    with pytest.raises(ValueError, match="must equal terminated | truncated; 1 entries differ"):
        validate_transitions(td)


def test_wrong_dtypes_and_shapes_are_rejected_with_a_fix():
    td = _transitions()
    td["observation"] = td["observation"].double()
    with pytest.raises(
        ValueError, match=r"must be float32, got torch.float64. Cast with .float\(\)"
    ):
        validate_transitions(td)
    td = _transitions()
    td["next", "reward"] = td["next", "reward"].squeeze(-1)
    with pytest.raises(ValueError, match=r"must have shape \[N, 1\]"):
        validate_transitions(td)
    with pytest.raises(ValueError, match="flat batch"):
        validate_transitions(_transitions(lengths=(2, 2)).reshape(2, 2))
    with pytest.raises(ValueError, match="Expected a TensorDict"):
        validate_transitions({"observation": torch.zeros(2, 3)})
