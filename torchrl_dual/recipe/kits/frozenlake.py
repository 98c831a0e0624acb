"""The Frozen-Lake kit (``env=frozenlake``): data, online env, exact evaluator, projection.

The data are generated epsilon-greedy episodes; the evaluator computes the greedy
policy's success probability exactly; the projection turns the actor's output into the
one-hot action the env takes. :data:`~torchrl_dual.recipe.settings.envs.ENV_KITS` names
these builders next to the ``env.*`` schema.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual._utils import one_hot_at
from torchrl_dual.data import OfflineDataset, load_or_generate_frozenlake_dataset
from torchrl_dual.envs import (
    frozenlake_num_states,
    frozenlake_success_probability,
    make_frozenlake_env,
)
from torchrl_dual.evaluation import frozenlake_policy_actions
from torchrl_dual.recipe.kits.build import Evaluator
from torchrl_dual.recipe.settings.structured import RecipeSettings


def frozenlake_data(settings: RecipeSettings) -> OfflineDataset:
    """The Frozen-Lake kit's ``D_offline``: epsilon-greedy episodes, cached on disk."""
    env = settings.env
    return load_or_generate_frozenlake_dataset(
        env.map_name,
        settings.budget.dataset_transitions,
        settings.seed,
        settings.data_cache_dir,
        success_rate=env.offline_success_rate,
        eval_success_rate=env.online_success_rate,
        epsilon=env.epsilon,
        max_episode_steps=env.max_episode_steps,
    )


def frozenlake_env(settings: RecipeSettings, data: OfflineDataset | None) -> EnvBase:
    """The Frozen-Lake kit's online env, at ``env.online_success_rate`` and ``env.shift``."""
    env = settings.env
    return make_frozenlake_env(
        env.map_name,
        success_rate=env.online_success_rate,
        seed=settings.seed,
        max_episode_steps=env.max_episode_steps,
        shift=env.shift,
    )


def frozenlake_evaluator(settings: RecipeSettings, data: OfflineDataset) -> Evaluator:
    """The exact success probability of the greedy policy (value iteration, no sampling)."""
    env = settings.env
    num_states = frozenlake_num_states(env.map_name)

    def success(actions: np.ndarray, shift: str) -> float:
        return float(
            frozenlake_success_probability(
                actions,
                env.map_name,
                env.online_success_rate,
                horizon=env.max_episode_steps,
                shift=shift,
            )
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        actions = frozenlake_policy_actions(policy, num_states, settings.device)
        shifted = success(actions, env.shift)
        result = {"return": shifted, "normalized_score": float(data.normalized_score(shifted))}
        if env.shift != "none":
            plain = success(actions, "none")
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = float(data.normalized_score(plain))
        return result

    return evaluate


def one_hot_argmax(action: torch.Tensor) -> torch.Tensor:
    """The executed discrete action as the one-hot vector the env receives, without a host read."""
    return one_hot_at(action.argmax(-1, keepdim=True), action, -1)
