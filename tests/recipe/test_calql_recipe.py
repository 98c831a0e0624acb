"""``algo=calql``: Cal-QL's critics (``critic=calql``) and SAC actor in the recipe, with the
Monte-Carlo bound on D_offline and on each finished online episode."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from test_diffql import CONFIG_DIR, POINTMAZE, checkpoint_state, common_overrides

from torchrl_dual.data import make_transitions, monte_carlo_returns
from torchrl_dual.recipe import ConfigError, compose_checked, run
from torchrl_dual.recipe.parts.mc_labels import MC_RETURN


@pytest.fixture(scope="module")
def calql_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("calql")
    cache = tmp_path_factory.mktemp("calql_data")
    overrides = ["algo=calql", *POINTMAZE, *common_overrides(out, cache)]
    return out, run(compose_checked(CONFIG_DIR, overrides))


def test_calql_runs_end_to_end_on_pointmaze(calql_run):
    out, result = calql_run
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 10 + 20)
    assert [h["label"] for h in state["history"]] == ["offline", "online"]
    assert set(state) >= {"critic", "critic_optimizer", "actor_optimizer"}
    assert "log_alpha" in state["critic"]
    scalars = out / "logs" / "calql" / "scalars"
    for name in ("loss_cql", "loss_qvalue", "loss_actor", "bound_rate"):
        assert (scalars / "offline" / f"{name}.csv").is_file(), name
    assert type(result.learner.critic.loss).__name__ == "CalQLLoss"


def test_offline_data_carries_its_monte_carlo_returns(calql_run):
    _, result = calql_run
    data = result.data.transitions
    expected = monte_carlo_returns(data, result.settings.critic.discount)
    assert torch.allclose(data[MC_RETURN], expected.float())
    batch = result.offline_buffer.sample()
    assert MC_RETURN in batch.keys()


def test_online_episodes_enter_the_buffer_labelled_when_they_end(calql_run):
    _, result = calql_run
    online = result.replay.online_buffer[:]
    assert len(online) > 0
    # every stored online transition belongs to a finished episode and carries its exact
    # return-to-go (PointMaze episodes here: 50 steps, truncated)
    assert bool(online["next", "done"][-1])
    expected = monte_carlo_returns(online, result.settings.critic.discount)
    assert torch.allclose(online[MC_RETURN], expected.float())


def test_an_unfinished_episode_is_held_until_it_ends(calql_run):
    _, result = calql_run
    learner = result.learner.labels
    learner.pending = None
    gamma = result.settings.critic.discount

    def piece(rewards, done_at=None, episode=0):
        n = len(rewards)
        done = torch.zeros(n, dtype=torch.bool)
        if done_at is not None:
            done[done_at] = True
        td = make_transitions(
            torch.zeros(n, 6),
            torch.zeros(n, 2),
            torch.zeros(n, 6),
            torch.tensor(rewards),
            done,
            torch.zeros(n, dtype=torch.bool),
            torch.full((n,), episode),
        )
        return td

    first = learner.online_transitions(piece([1.0, 0.0, 2.0]))
    assert len(first) == 0 and len(learner.pending) == 3
    second = learner.online_transitions(
        torch.cat([piece([1.0], done_at=0), piece([5.0, 5.0], episode=1)])
    )
    assert len(second) == 4 and len(learner.pending) == 2  # episode 0 out, episode 1 held
    rewards = [1.0, 0.0, 2.0, 1.0]
    by_hand = [sum(r * gamma**k for k, r in enumerate(rewards[t:])) for t in range(4)]
    assert torch.allclose(second[MC_RETURN].squeeze(-1), torch.tensor(by_hand))
    learner.pending = None


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["algo=calql", "critic=iql"], "critic=iql: calql supports calql"),
        (["algo=diffql", "critic=calql"], "critic=calql: diffql supports iql"),
        (
            ["algo=dual", "critic=calql", "actor.weighting=advantage"],
            "actor.weighting=advantage: needs IQL's value network V; critic=calql has none: "
            "use actor.weighting=sac (Q - alpha log pi, the paper's Cal-QL and SO2 rows) or uniform",
        ),
        (
            ["algo=dual", "critic=calql", "augment.kind=planner"],
            "augment.kind=planner: adds generated transitions without the Monte-Carlo bound "
            "of critic=calql; use augment.kind=none with critic=calql",
        ),
    ],
)
def test_critic_and_algorithm_must_match(tmp_path, overrides, message):
    with pytest.raises(ConfigError) as info:
        compose_checked(CONFIG_DIR, [f"output_dir={tmp_path}", "budget=smoke", *overrides])
    assert str(info.value) == message


def test_the_episode_in_progress_survives_an_interruption_cut(tmp_path):
    """40-step episodes, 50-frame blocks: stopped at 50 frames, 10 transitions wait in the
    checkpoint. The resumed run's collector starts a new episode, so the held one ends at
    the cut (truncated): at 100 frames 40 + 10 + 40 are labelled and 10 wait."""
    overrides = ["algo=calql", *common_overrides(tmp_path, tmp_path / "data")]
    overrides += ["env.max_episode_steps=40"]
    run(compose_checked(CONFIG_DIR, [*overrides, "interrupt_at_frames=50"]))
    assert len(checkpoint_state(tmp_path)["learner"]["pending"]) == 10
    finished = run(compose_checked(CONFIG_DIR, [*overrides, "resume=true"]))
    online = finished.replay.online_buffer[:]
    assert (finished.frames, len(online), len(finished.learner.labels.pending)) == (100, 90, 10)
    ends = online["next", "done"].squeeze(-1).nonzero().squeeze(-1).tolist()
    assert ends == [39, 49, 89]
    assert bool(online["next", "truncated"][49])  # the cut
    # three episodes, three ids: the cut one (held through the resume, so not among the
    # stored data the resumed run saw) keeps its id, the new one gets a fresh one
    ids = online["episode"].reshape(-1)
    assert [sorted(set(ids[a:b].tolist())) for a, b in ((0, 40), (40, 50), (50, 90))] == [
        [ids[0].item()],
        [ids[40].item()],
        [ids[50].item()],
    ]
    assert len({ids[0].item(), ids[40].item(), ids[50].item()}) == 3
    expected = monte_carlo_returns(online, finished.settings.critic.discount)
    assert torch.allclose(online[MC_RETURN], expected.float())
    by_hand = sum(
        float(r) * finished.settings.critic.discount**k
        for k, r in enumerate(online["next", "reward"][40:50].squeeze(-1))
    )
    assert float(online[MC_RETURN][40]) == pytest.approx(by_hand, rel=1e-5)


# ----------------------------------------------------------------------------- DUAL on Cal-QL
def test_dual_on_the_calql_critic_runs_resumes_and_saves_each_weight_once(tmp_path):
    """``algo=dual critic=calql``: Eq. 7 with the critic's preset ``sac`` weighting on
    Cal-QL's Q, the penalty sampling N(μ(s), σ̄²) of DUAL's own actor, the bound on both
    data sets; interrupted and resumed."""
    overrides = [
        "algo=dual",
        "critic=calql",
        *POINTMAZE,
        *common_overrides(tmp_path, tmp_path / "d"),
    ]
    overrides += ["env.max_episode_steps=40"]
    cfg = compose_checked(CONFIG_DIR, overrides)
    assert cfg.actor.weighting == "sac"
    run(compose_checked(CONFIG_DIR, [*overrides, "interrupt_at_frames=50"]))
    state = checkpoint_state(tmp_path)
    assert not any(k.startswith("actor_network_params") for k in state["critic"])
    assert any(k.startswith("qvalue_network_params") for k in state["critic"])
    assert len(state["learner"]["mc_labels"]["pending"]) == 10
    finished = run(compose_checked(CONFIG_DIR, [*overrides, "resume=true"]))
    learner = finished.learner
    # the penalty samples DUAL's actor itself (same parameters), not a copy
    actor_ptrs = {t.data_ptr() for t in TensorDict.from_module(learner.actor).values(True, True)}
    loss_params = learner.critic.loss.actor_network_params.values(True, True)
    assert actor_ptrs == {t.data_ptr() for t in loss_params}  # weights and buffers
    eq7 = learner.loss.actor_objective
    assert eq7.weighting == "sac" and eq7.value_network is None
    online = finished.replay.online_buffer[:]
    assert (finished.frames, len(online)) == (100, 90)
    expected = monte_carlo_returns(online, finished.settings.critic.discount)
    assert torch.allclose(online[MC_RETURN], expected.float())
    assert torch.allclose(
        finished.data.transitions[MC_RETURN],
        monte_carlo_returns(finished.data.transitions, finished.settings.critic.discount).float(),
    )
    scalars = tmp_path / "logs" / "dual" / "scalars"
    assert (scalars / "offline" / "loss_cql.csv").is_file()
    assert not (scalars / "offline" / "loss_value.csv").exists()
