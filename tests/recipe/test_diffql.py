"""The Diff-QL baselines ``algo=diffql`` and ``algo=diffql_la`` (``torchrl_dual/recipe/algos/diffql.py``).

End to end at a cut-down smoke budget (one run through ``recipes/o2o.py`` as a user
starts it, two in-process runs of :func:`torchrl_dual.recipe.run`, what it calls), then the math of the
pieces on tiny networks: the Q-term trains the actor and never the critic and does not
depend on the critic's scale, the BC term alone decreases, and "Diff-QL w LA"'s ensemble
spreads after a Laplace fit while its MAP mean is the actor's deterministic chain.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf
from recipe_runner import checkpoint_state, run_recipe, succeeded
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual import DDPMLastStepActor, WeightedMAPActorLoss, make_dual_policy
from torchrl_dual.objectives.diffql_actor_loss import DiffQLActorLoss, min_q
from torchrl_dual.recipe import CONFIG_DIR, O2ORun, check_command_line, compose_checked, run
from torchrl_dual.recipe.algos.diffql import ActionBox, DiffQLLALearner, make_diffusion_actor
from torchrl_dual.recipe.parts.critics import make_iql_critic
from torchrl_dual.recipe.settings.baselines import DiffQLActorSettings
from torchrl_dual.recipe.settings.parts import IQLCriticSettings
from torchrl_dual.recipe.settings.rules import as_settings

# the smoke budget cut further: 10 offline updates, 100 online frames in 2 blocks of 50,
# each followed by 10 updates (UTD 0.2) and a Laplace refit (diffql_la)
FAST = [
    "budget.offline_updates=10",
    "online.utd_ratio=0.2",
    "budget.online_frames=100",
    "budget.frames_per_batch=50",
    "budget.eval_every=100",
    "budget.checkpoint_every=100",
    "budget.eval_episodes=2",
    "budget.laplace_refit_every=10",
]
POINTMAZE = ["env.max_episode_steps=50"]  # shorter reference and evaluation episodes


def common_overrides(output_dir: Path, cache_dir: Path) -> list[str]:
    return [
        "budget=smoke",
        f"output_dir={output_dir}",
        f"data_cache_dir={cache_dir}",
        "progress=false",
        "num_threads=1",
        *FAST,
    ]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("diffql_data")


def run_in_process(algo: str, output_dir: Path, cache_dir: Path):
    """What ``python recipes/o2o.py algo=<algo> ...`` runs, on PointMaze, in this process."""
    overrides = [f"algo={algo}", *POINTMAZE, *common_overrides(output_dir, cache_dir)]
    return run(compose_checked(CONFIG_DIR, overrides))


@pytest.fixture(scope="module")
def diffql_umaze(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("diffql_umaze")
    return out, run_in_process("diffql", out, cache_dir)


@pytest.fixture(scope="module")
def diffql_la_umaze(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("diffql_la_umaze")
    return out, run_in_process("diffql_la", out, cache_dir)


# ----------------------------------------------------------------------------- end to end
def test_diffql_runs_end_to_end_on_pointmaze(diffql_umaze):
    out, _ = diffql_umaze
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 10 + 20)
    assert [h["label"] for h in state["history"]] == ["offline", "online"]
    assert set(state) >= {"actor", "critic", "critic_optimizer", "actor_optimizer"}
    # the score network at the smoke width, the same IQL critics without an actor copy
    assert state["actor"]["module.score_network.0.weight"].shape == (64, 2 + 6 + 1)
    assert not any(name.startswith("actor_network_params") for name in state["critic"])
    scalars = out / "logs" / "diffql" / "scalars"
    assert (scalars / "offline" / "loss_q.csv").is_file()


def test_diffql_la_runs_end_to_end_on_frozenlake_with_one_hot_actions(cache_dir, tmp_path):
    out = tmp_path / "run"
    proc = succeeded(run_recipe(out, cache_dir, *FAST, "algo=diffql_la", "env=frozenlake"))
    assert "[diffql_la] normalized score at the end of the online phase:" in proc.stdout
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "laplace", "offline_eval"]
    assert {"actor", "ensemble"} <= set(state)
    # each weight once: the ensemble's own state is σ̄, the posterior and its draws
    shared = ("actor.sampler.", "actor.trunk.", "actor.head.")  # the DDPM actor's
    assert not any(k.startswith(shared) for k in state["ensemble"])
    assert {"actor.log_std", "weight_deviation", "bias_deviation"} <= set(state["ensemble"])
    actions = state["online_data"]["action"]  # executed: the env kit's one-hot projection
    assert ((actions == 0) | (actions == 1)).all() and (actions.sum(-1) == 1).all()


def test_diffql_la_runs_on_pointmaze_and_refits_its_posterior(diffql_la_umaze):
    out, result = diffql_la_umaze
    learner = result.learner
    assert isinstance(learner, DiffQLLALearner)
    # one fit offline, then one after each block of 10 online updates
    refits = out / "logs" / "diffql_la" / "scalars" / "laplace" / "prior_precision.csv"
    assert len(refits.read_text().splitlines()) == 3
    epistemic = out / "logs" / "diffql_la" / "scalars" / "online" / "epistemic_std.csv"
    assert all(float(line.split(",")[1]) > 0 for line in epistemic.read_text().splitlines())
    assert learner.ensemble.actor.sampler is learner.actor.module  # one set of weights
    own = learner.modules()["ensemble"]
    own.load_state_dict(own.state_dict())  # the checkpoint's round trip


def test_diffql_and_diffql_la_share_the_offline_phase_and_its_evaluation(
    diffql_umaze, diffql_la_umaze
):
    """Same seed, same training: the offline phases give the same weights, and the MAP
    mean that evaluates diffql_la is diffql's deterministic chain, so the offline
    evaluations agree exactly."""
    (_, plain), (_, la) = diffql_umaze, diffql_la_umaze
    assert plain.history[0]["label"] == la.history[0]["label"] == "offline"
    assert plain.history[0]["return"] == la.history[0]["return"]


def test_diffql_la_s_sigma_bar_maximises_the_weighted_gaussian_likelihood(cache_dir, tmp_path):
    """σ̄ after a fit maximises ``Σ_i w_i log N(a_i; μ(s_i), σ̄²)`` (Eq. 7 in σ̄ at the
    current mean): scaling it by 0.9 or 1.1 lowers the weighted log-likelihood."""
    overrides = ["algo=diffql_la", "env=frozenlake", *common_overrides(tmp_path, cache_dir)]
    cfg = compose_checked(CONFIG_DIR, [*overrides, "budget.online_frames=0"])
    learner = O2ORun(cfg, DiffQLLALearner).learner
    learner.fit_laplace()
    actor = learner.last_step
    batch = next(learner.run.all_transitions())
    weight = learner.laplace_weight_fn(batch)
    with torch.no_grad():
        mean = actor(batch["observation"])

    def log_likelihood(std: torch.Tensor) -> float:
        log_prob = torch.distributions.Normal(mean, std).log_prob(batch["action"]).sum(-1)
        return float((weight * log_prob).sum())

    std = actor.std.detach()
    assert log_likelihood(std) > max(log_likelihood(0.9 * std), log_likelihood(1.1 * std))


def test_a_shift_weight_for_diffql_la_exits_2_with_one_error_line(capsys):
    argv = ["algo=diffql_la", "exploration.shift_weight=0.5"]
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=argv)
    assert stop.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1
    assert errors[0].startswith("error: exploration.shift_weight=0.5: must be 0 for diffql_la")


def test_a_misspelt_diffql_key_exits_2_naming_the_right_one(capsys):
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=["algo=diffql", "actor.etaa=2"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "error: unknown key 'actor.etaa'; did you mean actor.eta?" in err


# ----------------------------------------------------------------------------- the math
OBS_DIM, ACTION_DIM = 3, 2


def tiny_cfg(eta: float = 1.0):
    return OmegaConf.create(
        {
            "device": "cpu",
            "actor": {
                "num_steps": 5,
                "hidden": 32,
                "depth": 2,
                "activation": "mish",
                "eta": eta,
                "lr": 3e-4,
                "max_grad_norm": 1.0,
            },
            "critic": {
                "name": "iql",
                "actor_weighting": "advantage",
                "hidden": 32,
                "depth": 2,
                "lr": 3e-4,
                "expectile": 0.7,
                "discount": 0.99,
                "target_update_tau": 0.005,
            },
        }
    )


def toy_batch(n: int = 128, seed: int = 0) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    observation = torch.randn(n, OBS_DIM, generator=gen)
    action = torch.tanh(observation[:, :ACTION_DIM] - 0.5 * observation[:, 2:])
    return TensorDict(observation=observation, action=action, batch_size=[n])


def pieces(eta: float = 1.0):
    torch.manual_seed(0)
    cfg = tiny_cfg(eta)
    actor = make_diffusion_actor(as_settings(DiffQLActorSettings, cfg.actor), OBS_DIM, ACTION_DIM)
    critic = make_iql_critic(as_settings(IQLCriticSettings, cfg.critic), OBS_DIM, ACTION_DIM)
    box = ActionBox(-torch.ones(ACTION_DIM), torch.ones(ACTION_DIM))
    return actor, critic, DiffQLActorLoss.from_iql(actor, critic.loss, box, eta=eta)


def critic_parameters(critic) -> list[torch.Tensor]:
    return list(critic.loss.parameters())


def test_the_q_term_reaches_every_actor_weight_and_no_critic_weight():
    actor, critic, loss = pieces()
    q_term, _ = loss.q_term(toy_batch()["observation"])
    q_term.backward()
    for name, p in actor.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    assert all(p.grad is None for p in critic_parameters(critic))


def test_the_q_term_is_invariant_to_the_critic_s_scale():
    """Wang et al.'s normalisation: ``−mean Q / mean |Q|`` has the same actor gradient
    when every Q is multiplied by c > 0 (here the last layer of both Q networks by 7)."""
    actor, critic, loss = pieces()
    observation = toy_batch()["observation"]

    def gradient() -> torch.Tensor:
        actor.zero_grad()
        torch.manual_seed(1)  # the same chain noise
        loss.q_term(observation)[0].backward()
        return torch.cat([p.grad.flatten() for p in actor.parameters()])

    before = gradient()
    params = critic.loss.qvalue_network_params
    last = sorted(k for k in params.keys(True, True) if k[-1] == "weight")[-1]
    bias = (*last[:-1], "bias")
    with torch.no_grad():
        params.get(last).mul_(7.0)
        params.get(bias).mul_(7.0)
    torch.testing.assert_close(gradient(), before, rtol=1e-4, atol=1e-6)


def test_min_q_is_the_smaller_twin_and_differentiable_in_the_action():
    _, critic, _ = pieces()
    batch = toy_batch(16)
    action = batch["action"].clone().requires_grad_(True)
    network = critic.loss.qvalue_network
    q = min_q(network, critic.loss.qvalue_network_params, batch["observation"], action)
    twins = []
    for member in critic.loss.qvalue_network_params.unbind(0):
        with member.to_module(network):
            twins.append(network(batch.clone())["state_action_value"].squeeze(-1))
    torch.testing.assert_close(q, torch.minimum(*twins).detach())
    q.sum().backward()
    assert action.grad.abs().sum() > 0


def test_the_bc_term_alone_decreases_on_a_toy_batch():
    actor, _, loss = pieces(eta=0.0)
    optimizer = torch.optim.Adam(actor.parameters(), lr=3e-3)
    batch = toy_batch(256)
    history = []
    torch.manual_seed(2)
    for _ in range(150):
        bc = loss(batch)["loss_actor"]  # eta = 0: L_bc alone
        optimizer.zero_grad()
        bc.backward()
        optimizer.step()
        history.append(bc.item())
    first, last = sum(history[:20]) / 20, sum(history[-20:]) / 20
    assert last < 0.6 * first, (first, last)


def test_diffql_la_members_differ_after_a_fit_and_its_map_mean_is_the_actor_s_chain():
    actor, critic, _ = pieces()
    last_step = DDPMLastStepActor(actor, latent="zero", init_std=0.3)
    weights = WeightedMAPActorLoss.from_iql(last_step, critic.loss, temperature=3.0)
    spec = Bounded(-1.0, 1.0, shape=(ACTION_DIM,))
    policy = make_dual_policy(last_step, spec, num_samples=5, shift_weight=0.0)
    ensemble = policy[0]
    ensemble.fit_laplace([toy_batch(512)], weight_fn=weights.advantage_weights)
    observation = toy_batch(8, seed=3)["observation"]
    with torch.no_grad():
        members = ensemble.member_actions(observation)  # [M, B, A]
        assert members.var(0).min() > 0
        with set_exploration_type(ExplorationType.RANDOM):
            out = policy(TensorDict(observation=observation, batch_size=[8]))
        assert (out["epistemic_variance"] > 0).all()
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            mean = ensemble(TensorDict(observation=observation, batch_size=[8]))["action"]
            chain = actor(TensorDict(observation=observation, batch_size=[8]))["action"]
    torch.testing.assert_close(mean, last_step(observation).clamp(-1, 1))
    torch.testing.assert_close(mean, chain.clamp(-1, 1), rtol=1e-5, atol=1e-5)
    assert isinstance(last_step.head, nn.Linear)
