"""The "IQL + LA" baseline ``algo=iql_la`` (``torchrl_dual/recipe/algos/iql_la.py``).

End to end at a cut-down smoke budget: one PointMaze run through ``recipes/o2o.py`` as a
user starts it, one Frozen-Lake run in-process whose learner the tests inspect. Then:
the acting members are the tanh-squashed Laplace draws of IQL's own ``loc`` head, ``σ̄``
is the IQL actor's RMS std, the evaluation is IQL's deterministic action, the critics
and the actor start from the same weights as ``algo=iql``, the checkpoint holds each
weight once, and a shift weight is refused with one ``error:`` line.
"""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from test_o2o import checkpoint_state, csv_steps, run_recipe, succeeded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.recipe import (
    CONFIG_DIR,
    IQLLearner,
    O2ORun,
    check_command_line,
    compose_checked,
    run,
)
from torchrl_dual.recipe.algos.iql_la import IQLLALearner

REPO = Path(__file__).resolve().parents[2]
# the smoke budget cut further: 20 offline updates, 100 online frames in 2 blocks of 25
# updates, a refit after every block
FAST = [
    "budget.offline_updates=20",
    "budget.online_frames=100",
    "budget.frames_per_batch=50",
    "budget.eval_every=100",
    "budget.checkpoint_every=100",
    "budget.eval_episodes=2",
    "budget.laplace_refit_every=20",
]


def fast_cfg(output_dir: Path, cache_dir: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [
            "budget=smoke",
            f"output_dir={output_dir}",
            f"data_cache_dir={cache_dir}",
            "progress=false",
            "num_threads=1",
            *FAST,
            *overrides,
        ],
    )


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("iql_la_data")


@pytest.fixture(scope="module")
def frozenlake(tmp_path_factory, cache_dir) -> O2ORun:
    """A finished in-process Frozen-Lake run of ``algo=iql_la``."""
    out = tmp_path_factory.mktemp("iql_la_frozenlake")
    return run(fast_cfg(out, cache_dir, "algo=iql_la", "env=frozenlake"))


# ----------------------------------------------------------------------------- end to end
def test_iql_la_runs_end_to_end_on_pointmaze_and_refits_after_each_block(cache_dir, tmp_path):
    out = tmp_path / "run"
    proc = succeeded(run_recipe(out, cache_dir, "algo=iql_la", *FAST))
    assert "[iql_la] normalized score after the offline phase:" in proc.stdout
    assert "[iql_la] normalized score at the end of the online phase:" in proc.stdout
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "laplace", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 20 + 50)
    scalars = out / "logs" / "iql_la" / "scalars"
    # one fit offline (after 20 updates), then one after each block of 25 >= 20 updates
    assert csv_steps(scalars / "laplace" / "prior_precision.csv") == [20, 45, 70]
    epistemic = (scalars / "online" / "epistemic_std.csv").read_text().splitlines()
    assert len(epistemic) == 2 and all(float(line.split(",")[1]) > 0 for line in epistemic)
    # each weight once: the IQL loss holds the actor, the ensemble only its own state
    assert any(name.startswith("actor_network_params") for name in state["critic"])
    ensemble = state["ensemble"]
    assert {"actor.log_std", "weight_deviation", "laplace.theta_map"} <= set(ensemble)
    assert not [n for n in ensemble if n.startswith(("actor.trunk.", "actor.head."))]


def test_iql_la_on_frozenlake_stores_the_projected_one_hot_actions(frozenlake):
    assert frozenlake.learner.title == "IQL + LA"
    actions = frozenlake.replay.online_buffer[:]["action"]
    assert len(actions) == 100
    assert ((actions == 0) | (actions == 1)).all() and (actions.sum(-1) == 1).all()


# ----------------------------------------------------------------------------- the policy
def observations(run_: O2ORun, n: int = 32) -> torch.Tensor:
    return run_.data.transitions["observation"][:n]


def test_the_acting_members_are_the_squashed_laplace_draws_of_iql_s_loc_head(frozenlake):
    learner = frozenlake.learner
    ensemble, iql_net = learner.ensemble, learner.actor.module[0].module
    assert learner.head_actor.head is iql_net[0][-1]  # IQL's weights, shared
    obs = observations(frozenlake)
    with torch.no_grad():
        features = torch.nn.Sequential(*list(iql_net[0])[:-1])(obs)
        loc_rows = slice(0, learner.head_actor.action_dim)
        weight = iql_net[0][-1].weight[loc_rows] + ensemble.weight_deviation  # [M, A, d]
        bias = iql_net[0][-1].bias[loc_rows] + ensemble.bias_deviation
        pre = torch.einsum("bd,mad->mba", features, weight) + bias[:, None]
        expected = 0.5 + 0.5 * torch.tanh(pre)  # Frozen-Lake's box is [0, 1]
        torch.testing.assert_close(ensemble.member_actions(obs), expected)
        with set_exploration_type(ExplorationType.RANDOM):
            td = learner.exploration_policy(TensorDict(observation=obs, batch_size=[len(obs)]))
    torch.testing.assert_close(td["loc"], expected.mean(0))
    torch.testing.assert_close(td["epistemic_variance"], expected.var(0, correction=0))
    assert (td["epistemic_variance"] > 0).all()  # the posterior spreads the members
    assert ensemble.weight_deviation.abs().sum() > 0


def test_sigma_bar_is_the_rms_of_the_iql_actor_s_std_on_the_fit_data(frozenlake):
    learner = frozenlake.learner
    learner.fit_laplace()
    with torch.no_grad():
        obs = torch.cat([batch["observation"] for batch in frozenlake.all_transitions()])
        scale = learner.actor.module[0](TensorDict(observation=obs, batch_size=[len(obs)]))
    rms = scale["scale"].square().mean(0).sqrt().clamp(1e-3, 2.0)
    torch.testing.assert_close(learner.head_actor.std, rms)
    frozenlake.settings.laplace.noise_std = 0.25  # a fixed σ̄ instead
    try:
        learner.fit_laplace()
        torch.testing.assert_close(learner.head_actor.std, torch.full((4,), 0.25))
    finally:
        frozenlake.settings.laplace.noise_std = "iql"
        learner.fit_laplace()


def test_the_evaluation_is_iql_s_deterministic_action_and_the_ensemble_s_map(frozenlake):
    learner = frozenlake.learner
    assert learner.evaluation_policy is learner.actor  # the Gaussian actor, as algo=iql
    td = TensorDict(observation=observations(frozenlake), batch_size=[32])
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        iql_action = learner.evaluation_policy(td.clone())["action"]
        map_action = learner.ensemble(td.clone())["action"]
    torch.testing.assert_close(map_action, iql_action)


def test_iql_la_starts_from_iql_s_weights_for_the_same_seed(frozenlake, cache_dir, tmp_path):
    def learner(algo: str, learner_class: type, *overrides: str):
        cfg = fast_cfg(tmp_path / algo, cache_dir, f"algo={algo}", "env=frozenlake", *overrides)
        return O2ORun(cfg, learner_class).learner

    iql = learner("iql", IQLLearner)  # both default to the Gaussian actor
    iql_la = learner("iql_la", IQLLALearner)
    for theirs, ours in ((iql.actor, iql_la.actor), (iql.critic.loss, iql_la.critic.loss)):
        expected = theirs.state_dict()
        got = ours.state_dict()
        assert got.keys() == expected.keys()
        for name, value in expected.items():
            torch.testing.assert_close(got[name], value, msg=name)


def test_the_ensemble_state_round_trips_without_the_shared_weights(frozenlake):
    own = frozenlake.learner.modules()["ensemble"]
    saved = copy.deepcopy(own.state_dict())
    ensemble = frozenlake.learner.ensemble
    with torch.no_grad():
        ensemble.weight_deviation.add_(1.0)
        frozenlake.learner.head_actor.log_std.add_(0.1)
    own.load_state_dict(saved)
    torch.testing.assert_close(ensemble.weight_deviation, saved["weight_deviation"])
    torch.testing.assert_close(frozenlake.learner.head_actor.log_std, saved["actor.log_std"])
    with pytest.raises(RuntimeError, match="missing \\['weight_deviation'\\]"):
        own.load_state_dict({k: v for k, v in saved.items() if k != "weight_deviation"})


def test_a_resumed_run_restores_the_ensemble_and_acts_like_the_checkpointed_one(frozenlake):
    out = Path(frozenlake.settings.output_dir)
    saved = checkpoint_state(out)
    cache = Path(frozenlake.settings.data_cache_dir)
    cfg = fast_cfg(out, cache, "algo=iql_la", "env=frozenlake", "resume=true")
    resumed = O2ORun(cfg, IQLLALearner).learner
    for name in ("weight_deviation", "bias_deviation", "actor.log_std", "laplace.theta_map"):
        torch.testing.assert_close(resumed.ensemble.state_dict()[name], saved["ensemble"][name])
    assert resumed.refits.since == saved["learner"]["updates_since_refit"]
    # the trained IQL actor came back through IQL's loss, and with it the shared head
    for name, value in frozenlake.learner.actor.state_dict().items():
        torch.testing.assert_close(resumed.actor.state_dict()[name], value, msg=name)
    obs = observations(frozenlake)
    head = resumed.head_actor.head
    assert head.weight.data_ptr() == resumed.actor.module[0].module[0][-1].weight.data_ptr()
    with torch.no_grad():
        pre = torch.nn.functional.linear(
            resumed.head_actor.features(obs), *resumed.head_actor.head_parameters()
        )
        expected = 0.5 + 0.5 * torch.tanh(
            pre
            + torch.einsum(
                "bd,mad->mba",
                resumed.head_actor.features(obs),
                saved["ensemble"]["weight_deviation"],
            )
            + saved["ensemble"]["bias_deviation"][:, None]
        )
        torch.testing.assert_close(resumed.ensemble.member_actions(obs), expected)


# ----------------------------------------------------------------------------- config
def test_a_shift_weight_for_iql_la_exits_2_naming_the_missing_transition_model(capsys):
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=["algo=iql_la", "exploration.shift_weight=0.5"])
    assert stop.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert errors == [
        "error: exploration.shift_weight=0.5: must be 0 for iql_la: its actor has no "
        "transition model for Eq. 10's ŝ_t; shift-aware exploration is DUAL's (algo=dual)"
    ]


def test_a_misspelt_iql_la_key_exits_2_naming_the_right_one(capsys):
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=["algo=iql_la", "laplace.num_sample=3"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "error: unknown key 'laplace.num_sample'; did you mean laplace.num_samples?" in err


def test_a_noise_std_out_of_range_exits_2_saying_what_is_allowed(capsys):
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=["algo=iql_la", "laplace.noise_std=3"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "error: laplace.noise_std=3: must be 'iql' or a number in (0, 2]" in err


@pytest.mark.parametrize(
    ("distribution", "per_output"), [("gaussian", True), ("tanh_normal", False)]
)
def test_the_posterior_follows_the_actor_s_distribution(
    distribution, per_output, cache_dir, tmp_path
):
    """Gaussian ``N(c + r tanh(u), σ²)``: one Gram matrix per action dimension through the
    tanh (Gauss-Newton); ``TanhNormal``: one shared Gram matrix in the pre-tanh space."""
    cfg = fast_cfg(
        tmp_path, cache_dir, "algo=iql_la", "env=frozenlake", f"actor.distribution={distribution}"
    )
    learner = O2ORun(cfg, IQLLALearner).learner
    assert learner.head_actor.noise_after_squash is per_output
    assert learner.ensemble.laplace.per_output_jacobian is per_output
    learner.fit_laplace()
    assert learner.ensemble.laplace.G_raw.ndim == (3 if per_output else 2)
