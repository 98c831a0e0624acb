"""Factories of the O2O recipe: data, envs, evaluator, networks, losses and policy.

Each ``make_*`` builds one piece from the Hydra config; ``recipes/o2o.py`` composes them
into Algorithm 1.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from omegaconf import DictConfig
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import IQLLoss, SoftUpdate

from torchrl_dual import (
    LaplaceEnsembleActor,
    PlannerActor,
    ShiftAwareNoise,
    TransitionModel,
    WeightedMAPActorLoss,
)
from torchrl_dual.data import (
    OfflineDataset,
    load_or_generate_frozenlake_dataset,
    load_or_generate_maze_dataset,
    validate_transitions,
)
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.envs import make_frozenlake_env, make_pointmaze_env
from torchrl_dual.envs.frozenlake import frozenlake_num_states
from torchrl_dual.envs.frozenlake_mdp import frozenlake_success_probability
from torchrl_dual.envs.pointmaze import flatten_pointmaze_obs, make_pointmaze_gym_env
from torchrl_dual.evaluation import evaluate_episodes, frozenlake_policy_actions
from torchrl_dual.transforms import PreviousTransition

ENV_KINDS = ("pointmaze", "frozenlake")
CRITICS = ("iql",)


# ----------------------------------------------------------------------------- data and envs
def make_offline_dataset(cfg: DictConfig) -> OfflineDataset:
    """The offline data set D_offline, generated locally and cached (Alg. 1 line 1)."""
    env, budget = cfg.env, cfg.budget
    if env.kind == "pointmaze":
        data = load_or_generate_maze_dataset(
            env.maze,
            budget.dataset_transitions,
            cfg.seed,
            cfg.data_cache_dir,
            max_episode_steps=env.max_episode_steps,
        )
    elif env.kind == "frozenlake":
        data = load_or_generate_frozenlake_dataset(
            env.map_name,
            budget.dataset_transitions,
            cfg.seed,
            cfg.data_cache_dir,
            success_rate=env.offline_success_rate,
            eval_success_rate=env.online_success_rate,
            epsilon=env.epsilon,
            max_episode_steps=env.max_episode_steps,
        )
    else:
        raise ValueError(f"Unknown env.kind {env.kind!r}; choose one of {ENV_KINDS}.")
    validate_transitions(data.transitions)
    return data


def make_train_env(cfg: DictConfig):
    """The online env, with :class:`PreviousTransition` carrying ``(s_{t-1}, a_{t-1})``
    to the policy, which turns them into ``d_t`` of Eq. (10)."""
    env = cfg.env
    if env.kind == "pointmaze":
        base = make_pointmaze_env(
            env.maze, max_episode_steps=env.max_episode_steps, seed=cfg.seed, device="cpu"
        )
    else:
        base = make_frozenlake_env(
            env.map_name,
            success_rate=env.online_success_rate,
            seed=cfg.seed,
            max_episode_steps=env.max_episode_steps,
        )
    return base.append_transform(PreviousTransition())


def check_dims(env, data: OfflineDataset) -> None:
    """Fails fast when the data set and the env disagree on observation or action size."""
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_dim = env.action_spec.shape[-1]
    if (data.obs_dim, data.action_dim) != (obs_dim, action_dim):
        raise ValueError(
            f"The offline data has observation/action dims ({data.obs_dim}, "
            f"{data.action_dim}) but the env has ({obs_dim}, {action_dim}). Regenerate the "
            "data for this env (delete its cache entry) or pick the matching env."
        )


def make_evaluator(cfg: DictConfig, data: OfflineDataset) -> Callable[[nn.Module], dict]:
    """Deterministic evaluation returning the mean return and normalized score."""
    env = cfg.env
    device = cfg.device

    if env.kind == "frozenlake":
        num_states = frozenlake_num_states(env.map_name)

        def evaluate(policy) -> dict:
            actions = frozenlake_policy_actions(policy, num_states, device)
            success = float(
                frozenlake_success_probability(
                    actions,
                    env.map_name,
                    env.online_success_rate,
                    horizon=env.max_episode_steps,
                )
            )
            return {"return": success, "normalized_score": float(data.normalized_score(success))}

        return evaluate

    def make_gym_env():
        return make_pointmaze_gym_env(env.maze, max_episode_steps=env.max_episode_steps)

    def evaluate(policy) -> dict:
        returns = evaluate_episodes(
            make_gym_env,
            policy,
            cfg.budget.eval_episodes,
            observation_fn=flatten_pointmaze_obs,
            action_fn=lambda a: np.clip(a, -1.0, 1.0),
            seed=10_000 + cfg.seed,
            device=device,
        )
        mean = float(returns.mean())
        return {
            "return": mean,
            "return_std": float(returns.std()),
            "normalized_score": float(data.normalized_score(mean)),
        }

    return evaluate


def make_offline_buffer(data: OfflineDataset, cfg: DictConfig) -> ReplayBuffer:
    """Uniform transitions from D_offline; a plain ``ReplayBuffer`` so its samples carry
    the same keys as the online buffer of :class:`~torchrl.data.OfflineToOnlineReplayBuffer`."""
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(len(data), device=cfg.device),
        sampler=RandomSampler(),
        batch_size=cfg.online.batch_size,
    )
    buffer.extend(data.transitions)
    return buffer


def one_hot_argmax(action: torch.Tensor) -> torch.Tensor:
    """The executed discrete action as a one-hot vector (what the env receives)."""
    return nn.functional.one_hot(action.argmax(-1), action.shape[-1]).to(action.dtype)


# ----------------------------------------------------------------------------- networks
def make_planner(cfg: DictConfig, data: OfflineDataset) -> TrajectoryDiffusion:
    """The N-step diffusion planner g_θ' with its normalizer fitted on D_offline."""
    p = cfg.planner
    layout = TrajectoryLayout(data.obs_dim, data.action_dim, p.horizon)
    model = TrajectoryDiffusion(
        layout, num_steps=p.num_steps, schedule=p.schedule, hidden=p.hidden, depth=p.depth
    )
    model.normalizer.fit(data.transitions["observation"], data.transitions["action"])
    return model.to(cfg.device)


def one_step_like(teacher: TrajectoryDiffusion) -> TrajectoryDiffusion:
    """An untrained copy of the teacher's architecture with ``num_steps = 1`` (for loading)."""
    student = copy.deepcopy(teacher)
    student.num_steps = 1
    return student


@dataclass
class Critic:
    """TorchRL's IQL critics and what updates them."""

    loss: IQLLoss
    optimizer: torch.optim.Optimizer
    target_updater: SoftUpdate


class _GaussianHead(nn.Module):
    """``s -> (μ(s), σ̄)`` for the ProbabilisticActor IQLLoss needs at construction."""

    def __init__(self, actor: PlannerActor) -> None:
        super().__init__()
        self.actor = actor

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.actor(observation)
        return loc, self.actor.std.expand_as(loc)


def make_critic(cfg: DictConfig, actor: PlannerActor, data: OfflineDataset) -> Critic:
    """IQL's expectile value network V and twin Q networks (TorchRL ``IQLLoss``)."""
    c = cfg.critic
    if c.name not in CRITICS:
        raise ValueError(f"Unknown critic {c.name!r}; choose one of {CRITICS}.")
    cells = [c.hidden] * c.depth

    class _QNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = MLP(
                in_features=data.obs_dim + data.action_dim,
                out_features=1,
                num_cells=cells,
                activation_class=nn.ReLU,
            )

        def forward(self, observation, action):
            return self.mlp(torch.cat([observation, action], -1))

    qvalue = ValueOperator(_QNet(), in_keys=["observation", "action"])
    value = ValueOperator(
        MLP(in_features=data.obs_dim, out_features=1, num_cells=cells, activation_class=nn.ReLU),
        in_keys=["observation"],
    )
    policy = ProbabilisticActor(
        TensorDictModule(_GaussianHead(actor), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=torch.distributions.Normal,
    )
    loss = IQLLoss(
        policy, qvalue, value, expectile=c.expectile, num_qvalue_nets=2, loss_function="l2"
    ).to(cfg.device)
    loss.make_value_estimator(gamma=c.discount)
    params = list(loss.qvalue_network_params.values(True, True)) + list(
        loss.value_network_params.values(True, True)
    )
    optimizer = torch.optim.Adam(params, lr=c.lr)
    return Critic(loss, optimizer, SoftUpdate(loss, tau=c.target_update_tau))


def make_actor_loss(cfg: DictConfig, actor: PlannerActor, critic: Critic) -> WeightedMAPActorLoss:
    """The weighted MAP actor loss of Eq. (7) on the IQL critics."""
    a = cfg.actor
    return WeightedMAPActorLoss.from_iql(
        actor,
        critic.loss,
        weighting=a.weighting,
        temperature=a.temperature,
        max_weight=a.max_weight,
    )


TRANSITION_MODELS = ("frozen", "shared")


def make_actor(
    cfg: DictConfig, teacher: TrajectoryDiffusion, transition: TransitionModel
) -> PlannerActor:
    """The actor ``π_θ``: a one-step planner shaped like the teacher (weights loaded later).

    ``exploration.transition_model`` picks the ``ŝ_t`` of Eq. (10): ``frozen`` (default)
    keeps the distilled transition model's own weights (``transition``), ``shared`` uses
    the actor's fine-tuned ones (Alg. 1's ``p_θ``). Either way the policy answers both
    queries in one batched trunk pass.
    """
    source = cfg.exploration.transition_model
    if source not in TRANSITION_MODELS:
        raise ValueError(
            f"Unknown exploration.transition_model {source!r}; choose one of {TRANSITION_MODELS}."
        )
    return PlannerActor(
        one_step_like(teacher),
        latent=cfg.actor.latent,
        init_std=cfg.actor.init_std,
        transition_model=transition.sampler.model if source == "frozen" else None,
    )


def make_policies(
    cfg: DictConfig, actor: PlannerActor, env
) -> tuple[LaplaceEnsembleActor, TensorDictSequential]:
    """The Laplace ensemble (Eq. 9), which also predicts ``ŝ_t`` in its trunk pass, and the
    exploration policy with Eq. (10)'s noise."""
    low, high = env.action_spec.space.low, env.action_spec.space.high
    ensemble = LaplaceEnsembleActor(
        actor,
        num_samples=cfg.laplace.num_samples,
        prior_precision=cfg.laplace.prior_precision,
        action_low=low.to(cfg.device),
        action_high=high.to(cfg.device),
        sample_action=False,  # ShiftAwareNoise draws the executed action (Eq. 10)
        predict_transition=True,
    )
    noise = ShiftAwareNoise(
        spec=env.action_spec,
        shift_weight=cfg.exploration.shift_weight,
        action_projection=one_hot_argmax if cfg.env.kind == "frozenlake" else None,
    )
    return ensemble.to(cfg.device), TensorDictSequential(ensemble, noise).to(cfg.device)
