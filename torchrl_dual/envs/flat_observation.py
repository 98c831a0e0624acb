"""One flat, optionally normalized observation vector for any Gymnasium env.

The offline data of a Minari env kit (:mod:`torchrl_dual.data.minari`) flattens dict
observations in a fixed key order and may normalize states (CORL's ``normalize=True``);
the online env and the evaluation env must show the policy exactly the same vector.
:class:`FlatObservation` is that one map, applied on the Gymnasium side, so the training
env (a TorchRL :class:`~torchrl.envs.GymWrapper` around it) and the evaluator (which steps
Gymnasium envs directly) cannot disagree. :func:`make_flat_env` adds the TorchRL side:
float32, the reward transform ``r' = scale * r + shift`` (CORL's reward modification)
and a step counter.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch


def flat_dim(space: gym.Space, keys: Sequence[str] | None = None) -> int:
    """Size of the flat vector of an observation space (dict entries ``keys`` only).

    Args:
        space (gym.Space): a ``Box``, or a ``Dict`` of ``Box`` spaces.
        keys (sequence of str, optional): the dict entries counted (all if omitted).

    Returns:
        int: the number of entries of the flat vector.

    Raises:
        TypeError: a space other than ``Box`` or ``Dict``.

    Examples:
        >>> space = gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (2,)), "b": gym.spaces.Box(-1, 1, (3,))})
        >>> flat_dim(space), flat_dim(space, ["b"])
        (5, 3)
    """
    if isinstance(space, gym.spaces.Dict):
        names = list(keys) if keys is not None else sorted(space.spaces)
        return sum(flat_dim(space.spaces[k]) for k in names)
    if isinstance(space, gym.spaces.Box):
        return int(np.prod(space.shape))
    raise TypeError(f"FlatObservation handles Box and Dict spaces, got {type(space).__name__}.")


class FlatObservation(gym.ObservationWrapper):
    """Concatenates a dict observation's ``keys`` (in order) into float32 and normalizes it.

    ``observation(o) = (concat(o[k] for k in keys) - loc) / scale``; with ``loc`` and
    ``scale`` omitted the vector is only flattened.

    Args:
        env (gym.Env): a Gymnasium env with a ``Box`` or ``Dict`` of ``Box`` observations.
        keys (sequence of str, optional): dict entries in concatenation order (all,
            sorted, if omitted); must be ``None`` for a ``Box`` observation space.
        loc (array, optional): subtracted from the flat vector.
        scale (array, optional): divides the centred vector (entries must be > 0).

    Examples:
        >>> env = FlatObservation(gym.make("Pendulum-v1"), loc=np.ones(3), scale=2 * np.ones(3))
        >>> obs, _ = env.reset(seed=0)
        >>> raw, _ = gym.make("Pendulum-v1").reset(seed=0)
        >>> bool(np.allclose(obs, (raw - 1) / 2)), obs.dtype
        (True, dtype('float32'))
    """

    def __init__(
        self,
        env: gym.Env,
        keys: Sequence[str] | None = None,
        loc: np.ndarray | None = None,
        scale: np.ndarray | None = None,
    ) -> None:
        super().__init__(env)
        space = env.observation_space
        if keys is not None and not isinstance(space, gym.spaces.Dict):
            raise ValueError(f"keys={list(keys)} given but the observations are not a dict.")
        if isinstance(space, gym.spaces.Dict):
            keys = list(keys) if keys is not None else sorted(space.spaces)
            missing = [k for k in keys if k not in space.spaces]
            if missing:
                raise ValueError(
                    f"observation entries {missing} are not in the env's {sorted(space.spaces)}."
                )
        self.keys = None if keys is None else list(keys)
        dim = flat_dim(space, self.keys)
        self.loc = np.zeros(dim, np.float32) if loc is None else np.asarray(loc, np.float32)
        self.scale = np.ones(dim, np.float32) if scale is None else np.asarray(scale, np.float32)
        if self.loc.shape != (dim,) or self.scale.shape != (dim,):
            raise ValueError(
                f"loc and scale must have shape ({dim},), got {self.loc.shape} and "
                f"{self.scale.shape}."
            )
        if not (self.scale > 0).all():
            raise ValueError("scale must be > 0 everywhere.")
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)

    def flatten(self, observation: Any) -> np.ndarray:
        """The raw flat vector (before normalization)."""
        if self.keys is None:
            return np.asarray(observation, dtype=np.float32).reshape(-1)
        return np.concatenate(
            [np.asarray(observation[k], dtype=np.float32).reshape(-1) for k in self.keys]
        )

    def observation(self, observation: Any) -> np.ndarray:
        """The normalized flat vector ``(flatten(o) - loc) / scale``, float32 ``[dim]``.

        Args:
            observation: the env's (dict or array) observation.
        """
        return ((self.flatten(observation) - self.loc) / self.scale).astype(np.float32)


def reward_transforms(reward_scale: float = 1.0, reward_shift: float = 0.0) -> list:
    """The transforms of a reference's reward modification ``r' = scale * r + shift``.

    ``[RewardScaling(loc=reward_shift, scale=reward_scale)]``, or ``[]`` for the
    identity.

    Examples:
        >>> reward_transforms(), type(reward_transforms(10.0, -5.0)[0]).__name__
        ([], 'RewardScaling')
    """
    from torchrl.envs.transforms import RewardScaling

    if reward_scale == 1.0 and reward_shift == 0.0:
        return []
    return [RewardScaling(loc=float(reward_shift), scale=float(reward_scale))]


def make_flat_env(
    env: gym.Env,
    *,
    reward_scale: float = 1.0,
    reward_shift: float = 0.0,
    device: torch.device | str = "cpu",
    seed: int | None = None,
):
    """A TorchRL env around a :class:`FlatObservation` Gymnasium env.

    Transforms: ``DoubleToFloat`` -> ``RewardScaling(loc=reward_shift, scale=reward_scale)``
    (``r' = reward_scale * r + reward_shift``, only when not the identity) -> ``StepCounter``.

    Args:
        env (gym.Env): a :class:`FlatObservation` env (or any env with a flat ``Box``
            observation space).

    Keyword Args:
        reward_scale (float): multiplies the reward. Defaults to 1.
        reward_shift (float): then added to it (CORL AntMaze: -1). Defaults to 0.
        device (torch.device or str): device of the output tensordicts.
        seed (int, optional): passed to :meth:`~torchrl.envs.EnvBase.set_seed`.

    Examples:
        >>> env = make_flat_env(FlatObservation(gym.make("Pendulum-v1", max_episode_steps=4)),
        ...     reward_shift=-1.0, seed=0)
        >>> rollout = env.rollout(4)
        >>> rollout["observation"].shape, bool((rollout["next", "reward"] <= -1).all())
        (torch.Size([4, 3]), True)
    """
    from torchrl.envs import Compose, DoubleToFloat, GymWrapper, StepCounter, TransformedEnv

    if not isinstance(env.observation_space, gym.spaces.Box):
        raise ValueError(
            "make_flat_env needs a flat Box observation space; wrap the env in FlatObservation."
        )
    transforms = [DoubleToFloat(), *reward_transforms(reward_scale, reward_shift), StepCounter()]
    torchrl_env = TransformedEnv(GymWrapper(env, device=device), Compose(*transforms))
    if seed is not None:
        torchrl_env.set_seed(seed)
    return torchrl_env
