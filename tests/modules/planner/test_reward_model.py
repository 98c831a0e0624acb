"""The reward model of planned transitions (``torchrl_dual/modules/planner/reward_model.py``):
it regresses a known reward and classifies a known terminal set, on raw-unit inputs."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from torchrl_dual.diffusion import Normalizer
from torchrl_dual.modules import RewardModel


def transitions(n: int) -> TensorDict:
    """States around 5 with scale 3 (the normalizer must standardise them), actions in
    [-1, 1]; ``r = (s'_0 − s_0) + a_0²``, terminal iff ``s'_1 > 6``."""
    s = 5 + 3 * torch.randn(n, 2)
    a = 2 * torch.rand(n, 1) - 1
    s_next = s + torch.cat([a, torch.randn(n, 1)], -1)
    reward = (s_next[:, :1] - s[:, :1]) + a**2
    return TensorDict(
        {
            "observation": s,
            "action": a,
            "next": {"observation": s_next, "reward": reward, "terminated": s_next[:, 1:] > 6},
        },
        batch_size=[n],
    )


def test_the_reward_model_fits_a_known_reward_and_terminal_function():
    torch.manual_seed(0)
    train = transitions(4096)
    normalizer = Normalizer(2, 1).fit(train["observation"], train["action"])
    model = RewardModel(normalizer, hidden=64)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(400):
        batch = train[torch.randint(4096, (256,))]
        loss, metrics = model.loss(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    test = transitions(2000)
    reward, terminated = model.predict(
        test["observation"], test["action"], test["next", "observation"]
    )
    target = test["next", "reward"]
    assert float((reward - target).square().mean()) < 0.05 * float(target.var())
    assert float((terminated == test["next", "terminated"]).float().mean()) > 0.95
    assert set(metrics) == {"reward_loss", "terminal_loss"}


def test_the_reward_model_keeps_its_own_copy_of_the_statistics():
    normalizer = Normalizer(2, 1)
    model = RewardModel(normalizer, hidden=8)
    normalizer.obs_mean.fill_(7.0)
    assert float(model.normalizer.obs_mean.abs().max()) == 0.0
    assert "normalizer.obs_mean" in model.state_dict()
