"""Deterministic policy evaluation: many episodes at once, or exactly for Frozen-Lake."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type


@torch.no_grad()
def evaluate_episodes(
    make_env: Callable[[], gym.Env],
    policy: TensorDictModuleBase,
    num_episodes: int,
    *,
    observation_fn: Callable[[object], np.ndarray],
    action_fn: Callable[[np.ndarray], object] = lambda a: a,
    seed: int = 0,
    device: torch.device | str = "cpu",
    observation_key: str = "observation",
    action_key: str = "action",
    envs: list[gym.Env] | None = None,
) -> np.ndarray:
    """Returns of ``num_episodes`` deterministic episodes run side by side.

    The policy sees one batched TensorDict per time step (one forward for all live
    episodes) under ``ExplorationType.DETERMINISTIC``; the Gymnasium envs are stepped
    directly, which is an order of magnitude cheaper than a TorchRL env per episode.
    ``observation_fn`` maps a raw observation to the policy's flat input (the same map
    as the training env's transforms) and ``action_fn`` the policy's action to the env's.
    Episode ``i`` starts from ``reset(seed=seed + i)``, which seeds the whole reset, so a
    kept env gives the returns a new one gives.

    ``envs`` keeps the envs from one call to the next (an evaluator's): its first
    ``num_episodes`` are reset and run, the missing ones built with ``make_env`` and
    appended; its owner closes them. Building a MuJoCo env parses its model, about 0.1 s
    for a PointMaze, which is most of a short evaluation. ``None`` (the default): the envs
    are built for this call and closed after it.

    Examples:
        >>> import gymnasium as gym, torch
        >>> from tensordict.nn import TensorDictModule
        >>> policy = TensorDictModule(lambda o: torch.zeros(*o.shape[:-1], 1),
        ...     in_keys=["observation"], out_keys=["action"])
        >>> returns = evaluate_episodes(lambda: gym.make("Pendulum-v1", max_episode_steps=5),
        ...     policy, 3, observation_fn=lambda o: o)
        >>> returns.shape
        (3,)
    """
    owned = envs is None
    kept = [] if envs is None else envs
    kept.extend(make_env() for _ in range(num_episodes - len(kept)))
    envs = kept[:num_episodes]
    observations = [env.reset(seed=seed + i)[0] for i, env in enumerate(envs)]
    returns = np.zeros(num_episodes)
    live = list(range(num_episodes))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        while live:
            batch = np.stack([observation_fn(observations[i]) for i in live]).astype(np.float32)
            td = TensorDict(
                {observation_key: torch.as_tensor(batch, device=device)}, batch_size=[len(live)]
            )
            actions = policy(td).get(action_key).cpu().numpy()
            still_live = []
            for row, i in enumerate(live):
                obs, reward, terminated, truncated, _ = envs[i].step(action_fn(actions[row]))
                returns[i] += float(reward)
                observations[i] = obs
                if not (terminated or truncated):
                    still_live.append(i)
            live = still_live
    for env in envs if owned else ():
        env.close()
    return returns


@torch.no_grad()
def frozenlake_policy_actions(
    policy: TensorDictModuleBase, num_states: int, device: torch.device | str = "cpu"
) -> np.ndarray:
    """The deterministic action (argmax of the one-hot action vector) in every cell."""
    states = torch.eye(num_states, device=device)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        actions = policy(TensorDict({"observation": states}, batch_size=[num_states]))["action"]
    return actions.argmax(-1).cpu().numpy()
