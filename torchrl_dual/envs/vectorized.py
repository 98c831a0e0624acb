"""Several copies of a TorchRL env over Gymnasium stepped as one batch: :func:`vectorized_env`.

The envs of this package (and the recipe's env kits) are a
:class:`~torchrl.envs.TransformedEnv` over a :class:`~torchrl.envs.GymWrapper` of a
Gymnasium env, with every env-specific part (dynamics shift, start cells, observation
normalization) on the Gymnasium side and the TorchRL transforms (dtype casts, reward
transforms, step counter, :class:`~torchrl_dual.transforms.PreviousTransition`) on top.
:func:`vectorized_env` keeps both: it takes the Gymnasium env of each of ``num_envs``
copies, steps them in one Gymnasium :class:`~gymnasium.vector.SyncVectorEnv` wrapped by
TorchRL's ``GymWrapper`` (batch size ``[num_envs]``), and applies one clone of the
copies' transforms to the whole batch. A step costs one pass through TorchRL and one
policy call for all envs instead of one each.

The vector env runs with ``autoreset_mode=DISABLED``: TorchRL resets the envs that are
done itself (``_reset`` mask, Gymnasium's ``reset_mask``), so every env keeps TorchRL's
reset semantics (the terminal observation in ``"next"``, a fresh episode after it) and
the transforms reset per env (``StepCounter``, ``PreviousTransition``).
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
from torchrl.envs import EnvBase, GymWrapper, TransformedEnv

__all__ = ["vectorized_env"]


def _gym_side(env: EnvBase) -> GymWrapper:
    base = env.base_env if isinstance(env, TransformedEnv) else env
    if not isinstance(base, GymWrapper) or base.batch_size:
        raise TypeError(
            "vectorized_env needs an unbatched TorchRL env over one Gymnasium env "
            f"(TransformedEnv(GymWrapper(...)) or GymWrapper), got {type(base).__name__} "
            f"with batch size {tuple(base.batch_size)}."
        )
    return base


def vectorized_env(make_env: Callable[[], EnvBase], num_envs: int) -> EnvBase:
    """``num_envs`` copies of ``make_env()`` stepped as one batch ``[num_envs]``.

    Args:
        make_env (callable): ``() -> env``, an unbatched ``TransformedEnv`` over a
            ``GymWrapper`` (or a bare ``GymWrapper``); called ``num_envs`` times.
        num_envs (int): how many envs (>= 1).

    Returns:
        A ``TransformedEnv(GymWrapper(SyncVectorEnv(...)), transforms)`` with the
        transforms of the first copy (cloned); seeding it (``set_seed(s)``) seeds env
        ``i`` with ``s + i``. Closing it closes the Gymnasium envs.

    Examples:
        >>> from torchrl_dual.envs import make_pointmaze_env
        >>> env = vectorized_env(lambda: make_pointmaze_env("umaze", max_episode_steps=5), 3)
        >>> _ = env.set_seed(0)
        >>> rollout = env.rollout(12, break_when_any_done=False)
        >>> rollout.shape, rollout["next", "step_count"][0, :7].flatten().tolist()
        (torch.Size([3, 12]), [1, 2, 3, 4, 5, 1, 2])
    """
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}.")
    envs = [make_env() for _ in range(num_envs)]
    first = _gym_side(envs[0])
    gym_envs = []
    for env in envs:
        wrapper = _gym_side(env)
        gym_envs.append(wrapper._env)
        wrapper.is_closed = True  # its Gymnasium env now belongs to the vector env
    vector = gym.vector.SyncVectorEnv(
        [lambda gym_env=gym_env: gym_env for gym_env in gym_envs],
        autoreset_mode=gym.vector.AutoresetMode.DISABLED,
    )
    base = GymWrapper(
        vector,
        device=first.device,
        categorical_action_encoding=first._categorical_action_encoding,
    )
    if not isinstance(envs[0], TransformedEnv):
        return base
    return TransformedEnv(base, envs[0].transform.clone())
