"""A bimodal toy data set of 1-D trajectories that go either left or right."""

from __future__ import annotations

import torch
from tensordict import TensorDict

LEFT_FRACTION = 0.3


def bimodal_transitions(num_episodes: int = 400, length: int = 12, seed: int = 0) -> TensorDict:
    """Episodes start near 0 and move with velocity -1 (30 %) or +1 (70 %) plus small noise."""
    gen = torch.Generator().manual_seed(seed)
    direction = torch.where(torch.rand(num_episodes, generator=gen) < LEFT_FRACTION, -1.0, 1.0)
    action = direction[:, None] + 0.05 * torch.randn(num_episodes, length, generator=gen)
    start = 0.1 * torch.randn(num_episodes, 1, generator=gen)
    position = torch.cat([start, start + torch.cumsum(0.5 * action, dim=1)], dim=1)
    episode = torch.arange(num_episodes)[:, None].expand(num_episodes, length)
    done = torch.zeros(num_episodes, length, 1, dtype=torch.bool)
    done[:, -1] = True
    td = TensorDict(
        {
            "observation": position[:, :-1, None],
            "action": action[..., None],
            "episode": episode,
            "next": {
                "observation": position[:, 1:, None],
                "reward": torch.zeros(num_episodes, length, 1),
                "done": done,
                "terminated": torch.zeros_like(done),
                "truncated": done.clone(),
            },
        },
        batch_size=[num_episodes, length],
    )
    return td.reshape(-1)


def mode_statistics(windows: torch.Tensor, observation: torch.Tensor) -> tuple[float, float]:
    """Fraction of windows going left, and mean RMS distance to the nearest true mode.

    ``windows`` is ``[B, L, 2]`` (position, action) in raw units; ``observation`` the
    ``[B, 1]`` start position. The true modes are the noiseless left/right paths.
    """
    length = windows.shape[1]
    steps = torch.arange(length, dtype=windows.dtype)
    modes = []
    for velocity in (-1.0, 1.0):
        position = observation + 0.5 * velocity * steps
        modes.append(torch.stack([position, torch.full_like(position, velocity)], dim=-1))
    dist = torch.stack([((windows - m) ** 2).mean((-2, -1)).sqrt() for m in modes], dim=-1)
    left = (windows[..., 1].mean(-1) < 0).float().mean()
    return float(left), float(dist.min(-1).values.mean())
