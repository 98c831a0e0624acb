"""Episode ids of collected transitions: :func:`assign_episodes`.

It maps TorchRL's ``("collector", "traj_ids")`` (unique across the workers of one
collector; Ray's remote collectors number them apart, see
:class:`~torchrl_dual.recipe.o2o.ray_collector.InterleavedTrajectories`) to the run's
episode ids, so that an episode that spans batches keeps its id and ids are never
reused, also after a resume (a resumed run's collector starts new trajectories,
numbered from the largest stored id + 1).
"""

from __future__ import annotations

import torch


def assign_episodes(
    traj_ids: torch.Tensor, done: torch.Tensor, open_episodes: dict[int, int], next_episode: int
) -> tuple[torch.Tensor, int]:
    """Episode ids of one collected batch from the collector's trajectory ids.

    A trajectory already in ``open_episodes`` (``traj_id -> episode``, its earlier part was
    stored before) keeps its episode; a new one gets the next fresh id, in the order of the
    trajectory ids. ``open_episodes`` is updated in place: trajectories of this batch
    without a ``done`` stay open. Returns the ids and the next fresh id.

    Args:
        traj_ids (torch.Tensor): ``("collector", "traj_ids")`` of the flattened batch.
        done (torch.Tensor): ``("next", "done")`` of the flattened batch, same shape.
        open_episodes (dict[int, int]): the open trajectories' episode ids (updated).
        next_episode (int): the smallest id no episode has yet.

    Examples:
        >>> open_episodes = {}
        >>> traj = torch.tensor([0, 0, 1, 1, 2, 2])  # two workers: 0 then 2, and 1
        >>> done = torch.tensor([False, True, False, False, False, False])
        >>> ids, nxt = assign_episodes(traj, done, open_episodes, 10)
        >>> ids.tolist(), nxt, open_episodes
        ([10, 10, 11, 11, 12, 12], 13, {1: 11, 2: 12})
        >>> done = torch.ones(3, dtype=torch.bool)
        >>> ids, nxt = assign_episodes(torch.tensor([2, 1, 3]), done, open_episodes, nxt)
        >>> ids.tolist(), nxt, open_episodes
        ([12, 11, 13], 14, {})
    """
    traj_ids = traj_ids.reshape(-1)
    done = done.reshape(-1).to(torch.long)
    trajectories, position = torch.unique(traj_ids, return_inverse=True)
    episodes = []
    for traj in trajectories.tolist():
        if traj in open_episodes:
            episodes.append(open_episodes.pop(traj))
        else:
            episodes.append(next_episode)
            next_episode += 1
    episode_of = torch.tensor(episodes, dtype=torch.long)
    ended = torch.zeros(len(trajectories), dtype=torch.long).index_add_(0, position, done)
    for traj, episode, end in zip(trajectories.tolist(), episodes, ended.tolist(), strict=True):
        if not end:
            open_episodes[traj] = episode
    return episode_of[position], next_episode
