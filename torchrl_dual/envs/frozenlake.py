"""Slippery Frozen-Lake with one-hot float observations and a continuous action interface.

The paper's transition shift is a change of slip level: ``success_rate`` 3/4 (slip 1/4)
offline and 2/3 (slip 1/3) online. Gymnasium 1.4 supports ``success_rate`` natively:
the agent moves as intended with probability ``success_rate`` and in each perpendicular
direction with probability ``(1 - success_rate) / 2``. The online-only ``shift``
``"biased_slip"`` (``"biased_slip_cw"``) sends every slip to the counter-clockwise
(clockwise) side instead, which changes the optimal policy (see
:mod:`~torchrl_dual.envs.shifts`).
"""

from __future__ import annotations

import torch

from torchrl_dual.envs.frozenlake_mdp import FROZENLAKE_HORIZON
from torchrl_dual.envs.onehot_action import ContinuousOneHotAction
from torchrl_dual.envs.shifts import apply_shift, check_shift

FROZENLAKE_MAPS: tuple[str, ...] = ("4x4", "8x8")
FROZENLAKE_NUM_ACTIONS = 4


def frozenlake_num_states(map_name: str) -> int:
    """Number of grid cells of a Frozen-Lake map.

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.

    Returns:
        int: the number of cells (states).

    Raises:
        ValueError: an unknown map.

    Examples:
        >>> frozenlake_num_states("4x4"), frozenlake_num_states("8x8")
        (16, 64)
    """
    if map_name not in FROZENLAKE_MAPS:
        raise ValueError(
            f"Unknown Frozen-Lake map {map_name!r}. Valid names: {list(FROZENLAKE_MAPS)}."
        )
    side = int(map_name.split("x")[0])
    return side * side


def make_frozenlake_env(
    map_name: str = "4x4",
    success_rate: float = 3 / 4,
    device: torch.device | str = "cpu",
    seed: int | None = None,
    *,
    max_episode_steps: int = FROZENLAKE_HORIZON,
    action_low: float = 0.0,
    shift: str = "none",
):
    """Creates slippery ``FrozenLake-v1`` as a TorchRL env for continuous policies.

    * ``"observation"``: float32 one-hot of the grid cell, shape ``[S]`` (16 or 64).
    * ``"action"``: float32 vector of size 4 in ``[action_low, 1]`` (a
      :class:`~torchrl.data.Bounded` spec); the env executes its argmax
      (0=left, 1=down, 2=right, 3=up) through :class:`ContinuousOneHotAction`.
    * reward 1 on reaching the goal, 0 otherwise; ``terminated`` on goal or hole,
      ``truncated`` after ``max_episode_steps`` (100, also for ``8x8``).

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): probability of the intended move. Defaults to 3/4.
        device (torch.device or str): output device. Defaults to ``"cpu"``.
        seed (int, optional): seed for :meth:`~torchrl.envs.EnvBase.set_seed`.

    Keyword Args:
        max_episode_steps (int): time limit. Defaults to 100.
        action_low (float): lower bound of the action box (``0.0``, or ``-1.0`` for
            tanh-squashed policies). Defaults to ``0.0``.
        shift (str): online dynamics shift, ``"none"`` (default), ``"biased_slip"`` or
            ``"biased_slip_cw"``; with a shift the base env is a
            :class:`~torchrl.envs.GymWrapper` around the shifted Gymnasium env.

    Examples:
        >>> env = make_frozenlake_env("4x4", success_rate=2 / 3, seed=0)
        >>> env.action_spec.shape, env.observation_spec["observation"].shape
        (torch.Size([4]), torch.Size([16]))
        >>> rollout = env.rollout(10)
        >>> rollout["action"].dtype, rollout["observation"].dtype
        (torch.float32, torch.float32)
    """
    from torchrl.envs import (
        Compose,
        DTypeCastTransform,
        GymEnv,
        GymWrapper,
        StepCounter,
        TransformedEnv,
    )

    frozenlake_num_states(map_name)  # validates the name
    if not 0.0 < success_rate <= 1.0:
        raise ValueError(f"success_rate must be in (0, 1], got {success_rate}.")
    check_shift(shift, "frozenlake")
    kwargs = {
        "map_name": map_name,
        "is_slippery": True,
        "success_rate": float(success_rate),
        "max_episode_steps": int(max_episode_steps),
    }
    if shift == "none":
        base = GymEnv("FrozenLake-v1", device=device, categorical_action_encoding=False, **kwargs)
    else:
        import gymnasium as gym

        shifted = apply_shift(gym.make("FrozenLake-v1", **kwargs), shift, kind="frozenlake")
        base = GymWrapper(shifted, device=device, categorical_action_encoding=False)
    env = TransformedEnv(
        base,
        Compose(
            DTypeCastTransform(torch.int64, torch.float32, in_keys=["observation"]),
            ContinuousOneHotAction(FROZENLAKE_NUM_ACTIONS, low=action_low),
            StepCounter(),
        ),
    )
    if seed is not None:
        env.set_seed(seed)
    return env
