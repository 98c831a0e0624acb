"""``algo=so2`` (SO2 + OFF2ON), ``algo=dual critic=so2`` and ``replay=balanced`` in the
recipe: SAC-N offline, SO2's online targets and ``k`` critic steps per actor step, and the
balanced replay's density ratio and priorities across an interrupt and a resume."""

from __future__ import annotations

import pytest
import torch
from omegaconf import OmegaConf
from test_diffql import CONFIG_DIR, POINTMAZE, checkpoint_state, common_overrides

from torchrl_dual.recipe import ConfigError, O2ORun, compose_checked, run
from torchrl_dual.recipe.algos.so2 import SO2Learner

# 3 members, 3 critic steps per actor step online; 10 offline updates, then 100 frames at
# UTD 0.2: 20 online updates, i.e. 60 online critic steps
SO2_FAST = ["critic.num_qvalue_nets=3", "critic.online_steps_per_update=3"]


def _adam_steps(optimizer_state: dict) -> int:
    return int(next(iter(optimizer_state["state"].values()))["step"])


@pytest.fixture(scope="module")
def so2_run(tmp_path_factory):
    """An SO2 run interrupted after its first online block, its checkpoint then, and the
    resumed run."""
    out = tmp_path_factory.mktemp("so2")
    cache = tmp_path_factory.mktemp("so2_data")
    overrides = ["algo=so2", *POINTMAZE, *SO2_FAST, *common_overrides(out, cache)]
    run(compose_checked(CONFIG_DIR, [*overrides, "interrupt_at_frames=50"]))
    interrupted = checkpoint_state(out)
    cfg = compose_checked(CONFIG_DIR, [*overrides, "resume=true"])
    reloaded = O2ORun(cfg, SO2Learner)  # what a resume starts from
    return out, interrupted, reloaded, run(cfg)


def test_so2_runs_with_k_critic_steps_per_actor_step(so2_run):
    out, _, _, result = so2_run
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 10 + 20)
    assert _adam_steps(state["actor_optimizer"]) == 10 + 20
    assert _adam_steps(state["critic_optimizer"]) == 10 + 20 * 3
    assert [h["label"] for h in state["history"]] == ["offline", "online"]
    loss = result.learner.critic.loss
    assert type(loss).__name__ == "SO2QLoss" and loss.num_qvalue_nets == 3
    scalars = out / "logs" / "so2" / "scalars"
    for name in ("loss_qvalue", "loss_actor", "entropy"):
        assert (scalars / "offline" / f"{name}.csv").is_file(), name
    for name in ("loss_density_ratio", "ratio_online", "priority_mean"):
        assert (scalars / "online" / f"{name}.csv").is_file(), name


def test_so2_targets_are_sac_n_offline_and_smoothed_per_member_online(so2_run):
    _, _, _, result = so2_run
    loss, cfg = result.learner.critic.loss, result.settings
    critic = result.learner.critic
    assert (loss.target_reduction, loss.policy_noise) == ("independent", 0.3)
    critic.phases(loss, online=False)
    assert (loss.target_reduction, loss.policy_noise) == ("min", 0.0)
    critic.phases(loss, online=True)
    assert loss.noise_clip == cfg.critic.noise_clip == 0.6


def test_balanced_replay_priorities_and_ratio_network_survive_a_resume(so2_run):
    _, interrupted, reloaded, result = so2_run
    saved = interrupted["replay"]
    assert interrupted["frames"] == 50
    buffer = reloaded.replay.buffer
    # refreshed priorities differ from the initial 1 and come back exactly on resume
    assert not torch.equal(saved["priorities"]["priority"], torch.ones_like(buffer._priority))
    assert torch.equal(buffer._priority, saved["priorities"]["priority"])
    assert buffer.max_priority == saved["priorities"]["max_priority"]
    ratio = reloaded.replay.loss.state_dict()
    assert all(torch.equal(ratio[k], v) for k, v in saved["ratio"].items())
    assert len(reloaded.replay.online_buffer) == 50
    assert len(result.replay.online_buffer) == 100


def test_dual_on_so2_critic_with_balanced_replay(tmp_path):
    cache = tmp_path / "data"
    overrides = [
        "algo=dual",
        "critic=so2",
        "replay=balanced",
        "critic.entropy_coef=0.1",  # not the loss's default: the wiring is under test
        *POINTMAZE,
        *SO2_FAST,
        *common_overrides(tmp_path / "run", cache),
    ]
    result = run(compose_checked(CONFIG_DIR, overrides))
    state = checkpoint_state(tmp_path / "run")
    assert state["updates"] == 10 + 20
    assert _adam_steps(state["critic_optimizer"]) == 10 + 20 * 3
    assert _adam_steps(state["actor_optimizer"]) == 10 + 20
    assert result.settings.actor.weighting == "sac"  # the critic's preset
    eq7 = result.learner.loss.actor_objective
    assert eq7.weighting == "sac"
    # one α for the targets and the actor, and the actor's Q read inside the action box
    assert eq7.entropy_coef == result.settings.critic.entropy_coef
    assert eq7.action_box.high.tolist() == [1.0, 1.0]
    # the critic's targets sample DUAL's own actor (N(mu, sigma-bar^2)), saved once
    assert not any(k.startswith("actor_network") for k in state["critic"])


def test_critics_without_v_refuse_the_advantage_weighting(tmp_path):
    overrides = [
        "algo=dual",
        "critic=so2",
        "actor.weighting=advantage",
        *common_overrides(tmp_path, tmp_path),
    ]
    with pytest.raises(ConfigError, match="critic=so2 has none: use actor.weighting=sac"):
        compose_checked(CONFIG_DIR, overrides)


def test_replay_choices_are_checked(tmp_path):
    base = common_overrides(tmp_path, tmp_path)
    with pytest.raises(ConfigError, match="replay.temperature"):
        compose_checked(CONFIG_DIR, ["replay=balanced", "replay.temperature=0", *base])
    cfg = compose_checked(CONFIG_DIR, ["algo=iql", *base])
    assert cfg.replay.name == "mixed"  # the default for every algorithm but so2
    cfg = compose_checked(CONFIG_DIR, ["algo=so2", *base])
    assert (cfg.replay.name, cfg.critic.name) == ("balanced", "so2")
    cfg = OmegaConf.to_container(cfg, resolve=True)
    assert cfg["replay"]["ratio_batch_size"] == cfg["budget"]["batch_size"]
