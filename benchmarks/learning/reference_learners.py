"""d3rlpy's IQL and Cal-QL as learners of the recipe's run (``reference_d3rlpy.py``).

Imported only inside ``.venv-reference``, where d3rlpy is installed. A
:class:`D3rlpyLearner` hands each batch of the recipe's replay (``D_offline`` and
``D_online`` mixed as ``algo=iql`` mixes them) to d3rlpy's ``impl.update`` as a
``TorchMiniBatch``, and acts with d3rlpy's own action rules: ``predict_best_action``
(IQL: the Gaussian's ``tanh`` mean; Cal-QL: ``tanh`` of the squashed Gaussian's mean)
for the evaluator and ``sample_action`` for the collector, clamped to the env's box
(d3rlpy's IQL samples an unsquashed Gaussian).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import d3rlpy
import torch
from d3rlpy.models.encoders import VectorEncoderFactory
from d3rlpy.torch_utility import TorchMiniBatch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn

from torchrl_dual.recipe import (
    CONFIG_DIR,
    ConfigError,
    Learner,
    O2ORun,
    RecipeSettings,
    compose_checked,
    run_o2o,
    user_errors,
)
from torchrl_dual.recipe.kits.build import projected_policy  # the same projection as algo=iql
from torchrl_dual.recipe.parts.mc_labels import MC_RETURN, MonteCarloLabels


def _encoder(section: Any) -> VectorEncoderFactory:
    """d3rlpy's MLP encoder of a recipe section's ``hidden`` × ``depth``."""
    return VectorEncoderFactory(hidden_units=[section.hidden] * section.depth)


def _shared(cfg: RecipeSettings) -> dict[str, Any]:
    """The settings both references take from the recipe: sizes, batch, γ, τ, rates."""
    return {
        "batch_size": cfg.online.batch_size,
        "gamma": cfg.critic.discount,
        "tau": cfg.critic.target_update_tau,
        "actor_learning_rate": cfg.actor.lr,
        "critic_learning_rate": cfg.critic.lr,
        "actor_encoder_factory": _encoder(cfg.actor),
        "critic_encoder_factory": _encoder(cfg.critic),
    }


def iql_config(cfg: RecipeSettings) -> Any:
    """d3rlpy's ``IQLConfig`` with the recipe's sizes, rates and IQL constants."""
    return d3rlpy.algos.IQLConfig(
        **_shared(cfg),
        expectile=cfg.critic.expectile,
        weight_temp=cfg.actor.temperature,
        value_encoder_factory=_encoder(cfg.critic),
    )


def calql_config(cfg: RecipeSettings) -> Any:
    """d3rlpy's ``CalQLConfig`` with the recipe's sizes, rates and penalty constants; the
    penalty's weight is ``critic.min_q_weight`` fixed (α = 1, no Lagrange tuning), as in
    Cal-QL's own code and ``algo=calql``."""
    return d3rlpy.algos.CalQLConfig(
        **_shared(cfg),
        temp_learning_rate=cfg.actor.lr,
        conservative_weight=cfg.critic.min_q_weight,
        alpha_learning_rate=0.0,  # the penalty's weight fixed (Cal-QL's code, algo=calql)
        initial_alpha=1.0,
        n_action_samples=cfg.critic.num_random,
    )


REFERENCES: dict[str, Callable[[RecipeSettings], Any]] = {"iql": iql_config, "calql": calql_config}
"""``algo`` -> the d3rlpy config that is its reference implementation."""


class _Act(nn.Module):
    """``observation -> action`` by one of d3rlpy's action rules, clamped to the box."""

    def __init__(self, rule: Callable[[torch.Tensor], torch.Tensor], low, high) -> None:
        super().__init__()
        self.rule = rule
        self.register_buffer("low", low.detach().clone())
        self.register_buffer("high", high.detach().clone())

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        flat = observation.reshape(-1, observation.shape[-1])
        action = self.rule(flat).reshape(*observation.shape[:-1], -1)
        return torch.clamp(action, self.low, self.high)


class D3rlpyLearner(Learner):
    """d3rlpy's algorithm for ``cfg.algo`` on the recipe's data, replay and evaluator."""

    shared_stages = ()  # never shares (or overwrites) the offline cache of algo=iql

    def __init__(self, run: O2ORun) -> None:
        self.run = run
        cfg = run.settings  # typed, as the recipe's learners read it
        if cfg.algo == "calql":
            self.labels = MonteCarloLabels(run)  # returns-to-go, as algo=calql labels them
        else:
            self.labels = None
        self.title = f"{cfg.algo} (d3rlpy {d3rlpy.__version__})"
        algo = REFERENCES[cfg.algo](cfg).create(device=str(cfg.device))
        algo.create_impl((run.data.obs_dim,), run.data.action_dim)
        self.impl = algo.impl
        self.grad_step = 0
        space = run.env.action_spec.space
        low, high = space.low.to(cfg.device), space.high.to(cfg.device)

        def act(rule: Callable) -> TensorDictModule:
            return TensorDictModule(
                _Act(rule, low, high), in_keys=["observation"], out_keys=["action"]
            )

        self.evaluation_policy = act(self.impl.predict_best_action)
        self.exploration_policy = projected_policy(cfg, act(self.impl.sample_action))

    def modules(self) -> dict[str, Any]:
        """d3rlpy's own checkpointer's objects (networks and optimizer wrappers)."""
        checkpointer = self.impl.modules.create_checkpointer(str(self.run.settings.device))
        return {f"d3rlpy_{name}": obj for name, obj in checkpointer.modules.items()}

    def offline_stages(self) -> list:
        return [("actor_critic", self.run.pretrain_updates)]

    def online_transitions(self, transitions: TensorDictBase) -> TensorDictBase:
        if self.labels is None:
            return transitions
        return self.labels.online_transitions(transitions)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One d3rlpy update (critic, actor, target) on the recipe's batch."""
        reward = batch["next", "reward"].reshape(-1, 1).float()
        returns = batch[MC_RETURN].reshape(-1, 1).float() if self.labels else reward * 0
        action = batch["action"].float()
        minibatch = TorchMiniBatch(
            observations=batch["observation"].float(),
            actions=action,
            rewards=reward,
            next_observations=batch["next", "observation"].float(),
            next_actions=torch.zeros_like(action),
            returns_to_go=returns,
            terminals=batch["next", "terminated"].reshape(-1, 1).float(),
            intervals=torch.ones_like(reward),
            device=str(self.run.settings.device),
        )
        metrics = self.impl.update(minibatch, self.grad_step)
        self.grad_step += 1
        return {f"d3rlpy_{name}": float(value) for name, value in metrics.items()}

    def state_dict(self) -> dict[str, Any]:
        state = {"grad_step": self.grad_step}
        if self.labels is not None:
            state["labels"] = self.labels.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.grad_step = int(state.get("grad_step", 0))
        if self.labels is not None and "labels" in state:
            self.labels.load_state_dict(state["labels"])


def run_reference(overrides: list[str]) -> None:
    """Composes the recipe's config for ``overrides`` (``algo`` picks the reference) and
    runs :class:`D3rlpyLearner` through the recipe's :func:`run_o2o`."""
    with user_errors(debug=any(o == "debug=true" for o in overrides)):
        cfg = compose_checked(CONFIG_DIR, overrides)
        if cfg.algo not in REFERENCES:
            raise ConfigError(
                "algo", cfg.algo, "no d3rlpy reference; choose one of " + ", ".join(REFERENCES)
            )
        run_o2o(cfg, D3rlpyLearner)
