"""The ``algo=dacer`` baseline (``torchrl_dual/recipe/algos/dacer.py``): Diff-QL with DACER's
entropy regulator online.

End to end in process at a cut-down smoke budget, interrupted after the first block of
collected frames and resumed (the checkpoint restores ``α``, its Adam state and the
counters; the resumed run finishes and logs ``α`` and ``Ĥ``); then the pieces on the
run's learner: the executed action is the chain's sample plus ``noise_scale · α · ε``,
clamped; evaluation is the noiseless zero-latent chain; one regulator step raises ``α``
below the target entropy and lowers it above; cross-key errors.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from test_diffql import CONFIG_DIR, POINTMAZE, checkpoint_state, common_overrides
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules.exploration import sampled_entropy
from torchrl_dual.recipe import O2ORun, check_command_line, compose_checked, run
from torchrl_dual.recipe.algos.dacer import DACERLearner
from torchrl_dual.recipe.algos.diffql import DiffQLLearner

# test_diffql.py's cut-down smoke budget (10 offline updates, 100 online frames in 2
# blocks of 50, 10 updates each), the regulator every 5 online updates on 8 states x 50
DACER_FAST = ["dacer.entropy_every=5", "dacer.num_states=8", "dacer.num_samples=50"]


def config(output_dir: Path, cache_dir: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [
            "algo=dacer",
            *POINTMAZE,
            *common_overrides(output_dir, cache_dir),
            *DACER_FAST,
            *overrides,
        ],
    )


def scalar_rows(output_dir: Path, name: str) -> list[tuple[int, float]]:
    path = output_dir / "logs" / "dacer" / "scalars" / "online" / f"{name}.csv"
    rows = [line.split(",") for line in path.read_text().splitlines()]
    return [(int(step), float(value)) for step, value in rows]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("dacer_data")


@pytest.fixture(scope="module")
def dacer_run(tmp_path_factory, cache_dir):
    """A run interrupted at 50 online frames (its checkpoint kept), a learner rebuilt from
    that checkpoint, and the resumed run to the end."""
    out = tmp_path_factory.mktemp("dacer_umaze")
    cache = cache_dir
    run(config(out, cache, "interrupt_at_frames=50"))
    interrupted = checkpoint_state(out)
    restored = O2ORun(config(out, cache, "resume=true"), DACERLearner).learner
    finished = run(config(out, cache, "resume=true"))
    return out, interrupted, restored, finished


# ----------------------------------------------------------------------------- end to end
def test_dacer_runs_resumes_and_logs_alpha_and_the_entropy_estimate(dacer_run):
    out, interrupted, _, finished = dacer_run
    assert (interrupted["frames"], interrupted["updates"]) == (50, 10 + 10)
    state = checkpoint_state(out)
    assert state["stages_done"] == ["actor_critic", "offline_eval"]
    assert (state["frames"], state["updates"]) == (100, 10 + 20)
    assert [h["label"] for h in state["history"]] == ["offline", "online"]
    assert {"actor", "critic", "exploration_noise", "alpha_optimizer"} <= set(state)
    # 20 online updates, a regulator step at the 1st, 6th, 11th and 16th
    assert state["learner"]["online_updates"] == 20
    assert state["alpha_optimizer"]["state"][0]["step"] == 4
    alpha, entropy = scalar_rows(out, "alpha"), scalar_rows(out, "entropy")
    assert [step for step, _ in alpha] == [step for step, _ in entropy] == [50, 100]
    log_alpha = float(state["exploration_noise"]["log_alpha"])
    assert alpha[-1][1] == pytest.approx(math.exp(log_alpha))
    assert entropy[-1][1] == pytest.approx(state["learner"]["entropy"])
    # each Adam step moves log α by at most ~lr (3e-2): 4 steps from log 3
    assert 0 < abs(log_alpha - math.log(3.0)) <= 4 * 0.03 + 1e-4
    assert finished.learner.noise.target_entropy == pytest.approx(-0.9 * 2)  # DACER's, A = 2


def test_resume_restores_alpha_its_optimizer_and_the_counters(dacer_run):
    _, interrupted, restored, _ = dacer_run
    saved = interrupted["exploration_noise"]["log_alpha"]
    assert float(saved) != pytest.approx(math.log(3.0))  # the regulator ran before the cut
    assert torch.equal(restored.noise.log_alpha.detach(), saved)
    assert restored.online_updates == interrupted["learner"]["online_updates"] == 10
    assert restored.entropy == interrupted["learner"]["entropy"]
    adam = restored.alpha_optimizer.state[restored.noise.log_alpha]
    assert float(adam["step"]) == 2  # the 1st and 6th online updates
    torch.testing.assert_close(
        adam["exp_avg"], interrupted["alpha_optimizer"]["state"][0]["exp_avg"]
    )


def test_the_offline_phase_is_diffql_s_to_the_last_weight(cache_dir, tmp_path):
    """Same seed and keys: Diff-QL's offline updates give ``dacer`` the same actor and
    critics (the regulator's state draws no random numbers and is not trained offline)."""
    weights = {}
    for algo, learner_class in (("diffql", DiffQLLearner), ("dacer", DACERLearner)):
        overrides = [f"algo={algo}", *POINTMAZE, *common_overrides(tmp_path / algo, cache_dir)]
        o2o = O2ORun(compose_checked(CONFIG_DIR, overrides), learner_class)
        o2o.pretrain_updates()
        weights[algo] = {k: v.state_dict() for k, v in o2o.learner.modules().items()}
    assert set(weights["dacer"]) - set(weights["diffql"]) == {
        "exploration_noise",
        "alpha_optimizer",
    }
    for name in ("actor", "critic"):
        for key, value in weights["diffql"][name].items():
            assert torch.equal(weights["dacer"][name][key], value), (name, key)


# ----------------------------------------------------------------------------- the pieces
def observations(n: int = 64, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(n, 6, generator=gen) * 2 - 1  # PointMaze: position, velocity, goal


def explore(learner, obs: torch.Tensor, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The chain's sample and the executed action of ``learner`` for ``obs``, with the same
    seed: the chain draws its latents first, then the noise draws ``ε``."""
    td = TensorDict(observation=obs, batch_size=obs.shape[:1])
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        torch.manual_seed(seed)
        chain = learner.actor(td.clone())["action"]
        torch.manual_seed(seed)
        executed = learner.exploration_policy(td.clone())["action"]
    return chain, executed


def test_the_collected_action_is_the_chain_s_sample_plus_noise_scale_alpha_eps_clamped(
    dacer_run,
):
    learner = dacer_run[3].learner
    std = 0.1 * learner.noise.alpha  # dacer.noise_scale · α
    assert learner.noise.std == pytest.approx(float(std))
    obs = observations(2000)
    chain, executed = explore(learner, obs, seed=7)
    torch.manual_seed(7)
    learner.actor(TensorDict(observation=obs, batch_size=[2000]))  # replay the chain's draws
    eps = torch.randn_like(chain)
    torch.testing.assert_close(executed, (chain + std * eps).clamp(-1, 1))
    # the barely trained chain leaves the box often; with a wide box the spread around
    # the same chain sample is the noise's alone
    box = learner.box
    low, high = box.low.clone(), box.high.clone()
    try:
        box.low.fill_(-1e3), box.high.fill_(1e3)
        chain, executed = explore(learner, obs, seed=8)
    finally:
        box.low.copy_(low), box.high.copy_(high)
    residual = executed - chain
    torch.testing.assert_close(residual.std(0), std.expand(2), rtol=0.05, atol=0)
    assert residual.mean(0).abs().max() < 4 * std / math.sqrt(2000)


def test_evaluation_is_the_noiseless_zero_latent_chain(dacer_run):
    learner = dacer_run[3].learner
    td = TensorDict(observation=observations(), batch_size=[64])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        first = learner.evaluation_policy(td.clone())["action"]
        again = learner.exploration_policy(td.clone())["action"]  # the noise is off too
        chain = learner.actor(td.clone())["action"].clamp(-1, 1)
    assert torch.equal(first, chain) and torch.equal(again, chain)


@pytest.mark.parametrize("gap, direction", [(+3.0, 1.0), (-3.0, -1.0)])
def test_one_regulator_step_raises_alpha_below_the_target_and_lowers_it_above(
    dacer_run, gap, direction
):
    """Target ``Ĥ + gap``: the estimate is below it for ``gap > 0`` (α rises by Adam's
    first-step ``lr``), above it for ``gap < 0`` (α falls)."""
    learner = dacer_run[2]  # the learner rebuilt from the checkpoint, not run further
    noise, optimizer = learner.noise, learner.alpha_optimizer
    state = (noise.state_dict(), optimizer.state_dict(), learner.entropy)
    try:
        obs = observations(8)
        torch.manual_seed(3)
        estimate = float(sampled_entropy(learner.noisy_actor, obs, 50).mean())
        optimizer.state.clear()  # a first Adam step: exactly lr · sign(H̄ − Ĥ)
        noise.target_entropy.fill_(estimate + gap)
        before = float(noise.log_alpha.detach())
        torch.manual_seed(3)
        assert learner.regulate(obs) == pytest.approx(estimate, abs=1e-5)
        assert float(noise.log_alpha.detach()) - before == pytest.approx(direction * 0.03, rel=1e-3)
    finally:
        noise.load_state_dict(state[0])
        optimizer.load_state_dict(state[1])
        learner.entropy = state[2]


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["dacer.num_samples=2"],
            "error: dacer.num_samples=2: must be >= dacer.num_components=3",
        ),
        (
            ["dacer.num_states=999"],
            "error: dacer.num_states=999: must be <= online.batch_size=256",
        ),
        (["dacer.noise_scale=0"], "error: dacer.noise_scale=0: must be a number > 0"),
        (
            ["dacer.target_entropy=abc"],
            "error: dacer.target_entropy=abc: must be null or a finite number",
        ),
    ],
)
def test_bad_dacer_keys_exit_2_with_one_error_line(capsys, argv, message):
    with pytest.raises(SystemExit) as stop:
        check_command_line(CONFIG_DIR, argv=["algo=dacer", *argv])
    assert stop.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(message), errors
