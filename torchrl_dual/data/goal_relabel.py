"""Relabel goal-reaching data to one fixed goal (D4RL's single-goal AntMaze, ``env.protocol=d4rl``).

Minari's AntMaze data reward each episode's own goal within 0.45; D4RL's task rewards one
goal within 0.5 and ends the episode there. :func:`relabel_to_goal` rewrites the rewards
and the episode boundaries of data in the transition layout accordingly:

* ``reward_t = 1`` if ``||xy(s'_t) - g|| <= radius`` else ``0``, with ``xy`` the position
  entries of the (unnormalized) next observation;
* a rewarded transition is terminal (``terminated``), as the task's episode ends there;
* the data's episode continues after it in the file, so a new episode id starts after every
  done transition (the layout allows ``done`` only on an episode's last transition).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase


def relabel_to_goal(
    transitions: TensorDictBase,
    goal: Sequence[float] | torch.Tensor,
    *,
    radius: float,
    position: slice = slice(0, 2),
) -> TensorDictBase:
    """Rewards, terminations and episode ids of ``transitions`` for reaching ``goal``.

    Args:
        transitions (TensorDictBase): data in the transition layout, observations not
            normalized yet.
        goal (sequence of float): the goal position.

    Keyword Args:
        radius (float): success radius (D4RL AntMaze: 0.5).
        position (slice): where the position sits in the observation. Defaults to the
            first two entries (``achieved_goal`` first).

    Returns:
        a new TensorDict (``transitions`` is left untouched).

    Examples:
        >>> import numpy as np
        >>> from torchrl_dual.data.transition_layout import make_transitions
        >>> xy = np.array([[0.0, 0.0], [0.0, 0.8], [0.0, 0.9], [0.0, 2.0]])
        >>> td = make_transitions(xy[:-1], np.zeros((3, 1)), xy[1:], np.zeros(3),
        ...     np.zeros(3, bool), np.array([0, 0, 1], bool), np.zeros(3, int))
        >>> out = relabel_to_goal(td, [0.0, 1.0], radius=0.5)
        >>> out["next", "reward"].squeeze(-1).tolist(), out["next", "terminated"].squeeze(-1).tolist()
        ([1.0, 1.0, 0.0], [True, True, False])
        >>> out["episode"].tolist()
        [0, 1, 2]
    """
    out = transitions.clone()
    next_obs = out["next", "observation"]
    goal_t = torch.as_tensor(goal, dtype=next_obs.dtype, device=next_obs.device)
    reached = (next_obs[..., position] - goal_t).norm(dim=-1) <= radius
    out["next", "reward"] = reached.to(out["next", "reward"].dtype).unsqueeze(-1)
    terminated = reached.unsqueeze(-1)
    out["next", "terminated"] = terminated
    truncated = out["next", "truncated"] & ~terminated
    out["next", "truncated"] = truncated
    done = terminated | truncated
    out["next", "done"] = done
    episode = out["episode"]
    # a new id after every done transition and wherever the data's own episode changes
    starts = torch.zeros_like(episode, dtype=torch.bool)
    starts[1:] = done.squeeze(-1)[:-1] | (episode[1:] != episode[:-1])
    out["episode"] = torch.cumsum(starts.long(), 0)
    return out
