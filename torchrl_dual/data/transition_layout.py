"""The project's transition layout: one flat TensorDict of transitions, batch ``[N]``.

* ``observation``: float32 ``[N, obs_dim]``
* ``action``: float32 ``[N, act_dim]``
* ``("next", "observation")``: float32 ``[N, obs_dim]``
* ``("next", "reward")``: float32 ``[N, 1]``
* ``("next", "terminated")``, ``("next", "truncated")``, ``("next", "done")``: bool ``[N, 1]``
* ``episode``: int64 ``[N]``

Transitions of one episode are stored contiguously, in time order, under one episode id,
so TorchRL's :class:`~torchrl.data.SliceSampler` (``traj_key="episode"``) never draws a
window across episodes.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

FLOAT_KEYS: tuple[NestedKey, ...] = (
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
)
FLAG_KEYS: tuple[NestedKey, ...] = (
    ("next", "terminated"),
    ("next", "truncated"),
    ("next", "done"),
)
TRANSITION_KEYS: tuple[NestedKey, ...] = (*FLOAT_KEYS, *FLAG_KEYS, "episode")
"""Every key a transition TensorDict must carry."""


def _name(key: NestedKey) -> str:
    """``'observation'`` or ``('next', 'reward')``: the key as the user would type it."""
    return repr(key) if isinstance(key, str) else repr(tuple(key))


def make_transitions(
    observation: np.ndarray | torch.Tensor,
    action: np.ndarray | torch.Tensor,
    next_observation: np.ndarray | torch.Tensor,
    reward: np.ndarray | torch.Tensor,
    terminated: np.ndarray | torch.Tensor,
    truncated: np.ndarray | torch.Tensor,
    episode: np.ndarray | torch.Tensor,
) -> TensorDict:
    """Assembles arrays into the transition layout (casting dtypes, reshaping flags).

    ``reward``, ``terminated``, ``truncated`` may be ``[N]`` or ``[N, 1]``;
    ``done`` is computed as ``terminated | truncated``.

    Args:
        observation (array or Tensor): ``s``, ``[N, obs_dim]``.
        action (array or Tensor): ``a``, ``[N, action_dim]``.
        next_observation (array or Tensor): ``s'``, ``[N, obs_dim]``.
        reward (array or Tensor): ``r``, ``[N]`` or ``[N, 1]``.
        terminated (array or Tensor): bool, ``[N]`` or ``[N, 1]``.
        truncated (array or Tensor): bool, ``[N]`` or ``[N, 1]``.
        episode (array or Tensor): integer episode ids, ``[N]``.

    Returns:
        TensorDict: ``[N]`` transitions under :data:`TRANSITION_KEYS` (float32 observations,
        actions and rewards, ``[N, 1]`` bool flags, ``done = terminated | truncated``).

    Examples:
        >>> n = 3
        >>> td = make_transitions(np.zeros((n, 2)), np.zeros((n, 1)), np.zeros((n, 2)),
        ...     np.zeros(n), np.zeros(n, bool), np.array([0, 0, 1], bool), np.zeros(n, int))
        >>> td["next", "done"].squeeze(-1).tolist()
        [False, False, True]
    """

    def as_tensor(x, dtype: torch.dtype) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x).to(dtype)

    obs = as_tensor(observation, torch.float32)
    n = obs.shape[0]
    term = as_tensor(terminated, torch.bool).reshape(n, 1)
    trunc = as_tensor(truncated, torch.bool).reshape(n, 1)
    return TensorDict(
        {
            "observation": obs.reshape(n, -1),
            "action": as_tensor(action, torch.float32).reshape(n, -1),
            "episode": as_tensor(episode, torch.int64).reshape(n),
            "next": {
                "observation": as_tensor(next_observation, torch.float32).reshape(n, -1),
                "reward": as_tensor(reward, torch.float32).reshape(n, 1),
                "terminated": term,
                "truncated": trunc,
                "done": term | trunc,
            },
        },
        batch_size=[n],
    )


def validate_transitions(
    td: TensorDictBase,
    obs_dim: int | None = None,
    action_dim: int | None = None,
) -> TensorDictBase:
    """Checks that ``td`` follows the transition layout; raises ``ValueError`` otherwise.

    Checked: presence of every key of :data:`TRANSITION_KEYS`, a 1-d batch, shapes and
    dtypes, ``obs_dim`` / ``action_dim`` if given, finite floats, ``done == terminated |
    truncated``, contiguous episodes, ``done`` only on an episode's last transition, and
    ``next.observation[t] == observation[t + 1]`` inside an episode.

    Args:
        td (TensorDictBase): the transitions.
        obs_dim (int, optional): expected observation size.
        action_dim (int, optional): expected action size.

    Returns:
        ``td`` itself, for chaining.

    Examples:
        >>> td = make_transitions(np.zeros((2, 3)), np.zeros((2, 1)), np.zeros((2, 3)),
        ...     np.zeros(2), np.zeros(2, bool), np.array([0, 1], bool), np.zeros(2, int))
        >>> _ = validate_transitions(td, obs_dim=3, action_dim=1)
        >>> try:
        ...     validate_transitions(td, obs_dim=4)
        ... except ValueError as err:
        ...     print(str(err)[:61])
        'observation' has size 3 on its last dim, expected obs_dim=4.
    """
    if not isinstance(td, TensorDictBase):
        raise ValueError(f"Expected a TensorDict of transitions, got {type(td).__name__}.")
    present = set(td.keys(include_nested=True, leaves_only=True))
    missing = [_name(k) for k in TRANSITION_KEYS if k not in present]
    if missing:
        raise ValueError(
            f"Transitions are missing the keys [{', '.join(missing)}]. Build them with "
            "torchrl_dual.data.make_transitions(...) or add the entries (done = terminated | truncated)."
        )
    if td.batch_dims != 1:
        raise ValueError(
            f"Transitions need a flat batch [N], got batch_size={tuple(td.batch_size)}. "
            "Flatten with td.reshape(-1)."
        )
    n = td.batch_size[0]
    dims = {"observation": obs_dim, ("next", "observation"): obs_dim, "action": action_dim}
    for key in FLOAT_KEYS:
        value = td.get(key)
        if value.dtype != torch.float32:
            raise ValueError(
                f"{_name(key)} must be float32, got {value.dtype}. Cast with .float()."
            )
        if key == ("next", "reward"):
            if value.shape != (n, 1):
                raise ValueError(
                    f"{_name(key)} must have shape [N, 1] = [{n}, 1], got {list(value.shape)}. "
                    "Use reward.unsqueeze(-1)."
                )
        elif value.ndim != 2:
            raise ValueError(
                f"{_name(key)} must have shape [N, dim], got {list(value.shape)}. "
                "Flatten with .reshape(N, -1)."
            )
        expected = dims.get(key)
        if expected is not None and value.shape[-1] != expected:
            arg = "obs_dim" if "observation" in _name(key) else "action_dim"
            raise ValueError(
                f"{_name(key)} has size {value.shape[-1]} on its last dim, expected "
                f"{arg}={expected}. Check the env/dataset pairing or the observation flattening."
            )
        bad = ~torch.isfinite(value)
        if bad.any():
            n_nan = int(torch.isnan(value).sum())
            n_inf = int(bad.sum()) - n_nan
            rows = bad.reshape(n, -1).any(-1).nonzero().squeeze(-1)[:5].tolist()
            raise ValueError(
                f"{_name(key)} has {n_nan} NaN and {n_inf} inf entries (first rows: {rows}). "
                "Drop or repair those transitions before training."
            )
    if td["observation"].shape[-1] != td["next", "observation"].shape[-1]:
        raise ValueError(
            f"'observation' and ('next', 'observation') differ in size: "
            f"{td['observation'].shape[-1]} vs {td['next', 'observation'].shape[-1]}."
        )
    for key in FLAG_KEYS:
        value = td.get(key)
        if value.dtype != torch.bool or value.shape != (n, 1):
            raise ValueError(
                f"{_name(key)} must be bool of shape [N, 1] = [{n}, 1], got {value.dtype} "
                f"{list(value.shape)}. Use .bool().reshape(-1, 1)."
            )
    done = td["next", "done"]
    if not torch.equal(done, td["next", "terminated"] | td["next", "truncated"]):
        count = int((done != (td["next", "terminated"] | td["next", "truncated"])).sum())
        raise ValueError(
            f"('next', 'done') must equal terminated | truncated; {count} entries differ."
        )
    episode = td["episode"]
    if episode.dtype != torch.int64 or episode.shape != (n,):
        raise ValueError(
            f"'episode' must be int64 of shape [N] = [{n}], got {episode.dtype} {list(episode.shape)}."
        )
    _check_episodes(td, episode, done.squeeze(-1))
    return td


def _check_episodes(td: TensorDictBase, episode: torch.Tensor, done: torch.Tensor) -> None:
    if episode.numel() == 0:
        return
    starts = torch.ones_like(episode, dtype=torch.bool)
    starts[1:] = episode[1:] != episode[:-1]
    blocks = episode[starts]
    if blocks.unique().numel() != blocks.numel():
        _, counts = blocks.unique(return_counts=True)
        split = blocks.unique()[counts > 1][:5].tolist()
        raise ValueError(
            f"Episodes are not contiguous: episode ids {split} appear in several separate "
            "blocks. Sort the transitions by (episode, time) or re-number the episodes."
        )
    last = torch.ones_like(starts)
    last[:-1] = starts[1:]
    early = done & ~last
    if early.any():
        rows = early.nonzero().squeeze(-1)[:5].tolist()
        raise ValueError(
            f"{int(early.sum())} transitions are done but not the last of their episode "
            f"(rows {rows}). Start a new episode id after every done transition."
        )
    same = ~last[:-1]
    if same.any():
        nxt = td["next", "observation"][:-1][same]
        obs = td["observation"][1:][same]
        mismatch = ~torch.isclose(nxt, obs, atol=1e-5, rtol=1e-5).all(-1)
        if mismatch.any():
            rows = same.nonzero().squeeze(-1)[mismatch][:5].tolist()
            raise ValueError(
                f"{int(mismatch.sum())} transitions have ('next', 'observation') different from "
                f"the following 'observation' of the same episode (rows {rows}). "
                "Episodes are out of order or the next observations are misaligned."
            )
