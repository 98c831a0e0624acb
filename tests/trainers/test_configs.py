"""DUAL's entries in TorchRL's ConfigStore, instantiated into a run that trains."""

import torch
from hydra.core.config_store import ConfigStore
from hydra.utils import instantiate
from omegaconf import OmegaConf

from tests.trainers.toy_dual import toy_parts
from torchrl_dual.modules import ShiftAwareNoise
from torchrl_dual.objectives import DUALLoss
from torchrl_dual.trainers import DUALTrainer, dual_collector, register_configs


def test_register_configs_lists_dual_next_to_torchrl_groups():
    register_configs()
    repo = ConfigStore.instance().repo
    assert "iql.yaml" in repo["loss"]  # TorchRL's own entries are there too
    for group, name in [
        ("loss", "dual"),
        ("loss", "dual_iql_critic"),
        ("loss", "dual_diffusion_planner"),
        ("loss", "dual_distillation"),
        ("exploration", "shift_aware_noise"),
        ("hook", "laplace_refit"),
        ("hook", "dual_signals"),
        ("hook", "normalized_score"),
        ("replay_buffer", "offline_to_online"),
        ("trainer", "dual"),
    ]:
        assert f"{name}.yaml" in repo[group], (group, name)


def test_stored_configs_instantiate_and_train(tmp_path):
    register_configs()
    repo = ConfigStore.instance().repo
    env, policy, stepper, replay, stages, runs, trained = toy_parts()
    # modules are not config values: Hydra builds a partial, the modules complete it
    critic_cfg = OmegaConf.structured(repo["loss"]["dual_iql_critic.yaml"].node)
    critic = instantiate(critic_cfg, _partial_=True)(
        qvalue_network=trained.critic.qvalue_network, value_network=trained.critic.value_network
    )
    loss_cfg = OmegaConf.structured(repo["loss"]["dual.yaml"].node)
    loss = instantiate(loss_cfg, temperature=2.0, _partial_=True)(
        actor=policy[0].actor, critic=critic
    )
    assert isinstance(loss, DUALLoss) and loss.actor_objective.temperature == 2.0
    # Eq. 7 reads the critic the loss trains: its weights, not the modules' initial ones
    loss.make_value_estimator(gamma=0.99)
    with torch.no_grad():
        critic.value_network_params.apply_(lambda p: p.add_(1.0))
    batch = replay.offline_buffer.sample(8)
    with critic.value_network_params.to_module(critic.value_network):
        expected = critic.value_network(batch.select("observation"))["state_value"]
    assert torch.equal(
        loss.actor_objective._evaluate(
            critic.value_network, loss.actor_objective.value_params, batch, "state_value"
        ),
        expected,
    )
    noise_cfg = OmegaConf.structured(repo["exploration"]["shift_aware_noise.yaml"].node)
    noise = instantiate(noise_cfg, shift_weight=0.25, _partial_=True)(spec=env.action_spec)
    assert isinstance(noise, ShiftAwareNoise) and noise.shift_weight == 0.25

    cfg = OmegaConf.structured(repo["trainer"]["dual.yaml"].node)
    cfg.total_frames, cfg.optim_steps_per_batch, cfg.refit_interval = 20, 2, 2
    cfg.progress_bar, cfg.batch_size = False, 16
    trainer = instantiate(cfg, _partial_=True)(
        collector=dual_collector(env, policy, frames_per_batch=20, total_frames=20),
        policy=policy,
        stepper=stepper,
        replay_buffer=replay,
        offline_stages=stages,
        weight_fn=trained.actor_objective.advantage_weights,
    )
    assert isinstance(trainer, DUALTrainer)
    trainer.train()
    assert runs == {"pretrain": 1, "laplace_fit": 1}
    assert trainer.collected_frames == 20 and trainer.laplace_refit.num_refits == 1


def test_the_store_is_restored_for_the_recipe_after_these_tests():
    """The recipe composes after a test here registered TorchRL's configs (conftest; an
    import of TorchRL's trainer configs elsewhere in the worker may have stored them too)."""
    from torchrl_dual.recipe import CONFIG_DIR, compose_checked

    assert compose_checked(CONFIG_DIR, ["budget=smoke"]).algo == "dual"


def test_the_recipe_composes_while_torchrl_s_configs_are_stored():
    """compose_checked hides the store's entries named like the recipe's groups (TorchRL's
    ``logger/csv`` schema would reject the recipe's) and puts them back afterwards."""
    from torchrl_dual.recipe import CONFIG_DIR, compose_checked

    register_configs()
    store = ConfigStore.instance().repo
    assert "csv.yaml" in store["logger"]  # TorchRL's logger/csv, a name the recipe uses too
    assert compose_checked(CONFIG_DIR, ["budget=smoke", "logger=csv"]).algo == "dual"
    assert "csv.yaml" in store["logger"]  # restored


def test_the_recipe_composes_inside_a_running_hydra_app():
    """A user's Hydra app calls compose_checked while its
    own GlobalHydra is initialized: the recipe composes apart, and the app's Hydra is back
    afterwards."""
    from hydra import compose, initialize
    from hydra.core.global_hydra import GlobalHydra

    from torchrl_dual.recipe import CONFIG_DIR, compose_checked

    register_configs()
    with initialize(version_base=None):
        running = GlobalHydra.instance().hydra
        assert compose_checked(CONFIG_DIR, ["budget=smoke", "algo=iql"]).algo == "iql"
        assert GlobalHydra.instance().hydra is running
        assert compose("trainer/dual").trainer is not None  # the app's store still composes
