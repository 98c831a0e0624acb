"""Tests of DACER's entropy-regulated noise (``torchrl_dual/modules/exploration/entropy_regulator.py``):
the noise's spread is ``noise_scale · α`` under RANDOM and nothing under DETERMINISTIC,
the temperature rule moves ``α`` toward the target entropy from either side, the
sampled estimate is per state, and the closed loop settles where ``Ĥ(α) = H̄``."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules.exploration import (
    EntropyRegulatedNoise,
    dacer_target_entropy,
    sampled_entropy,
)

LOG_2PI_E = 1 + math.log(2 * math.pi)


def fixed_chain(noise: EntropyRegulatedNoise) -> TensorDictSequential:
    """A deterministic "actor" (action = tanh of the state's first two entries), then ``noise``."""
    actor = TensorDictModule(
        lambda s: torch.tanh(s[..., :2]), in_keys=["observation"], out_keys=["action"]
    )
    return TensorDictSequential(actor, noise)


def test_the_collected_spread_around_a_fixed_chain_is_noise_scale_times_alpha():
    torch.manual_seed(0)
    noise = EntropyRegulatedNoise(target_entropy=-1.8, noise_scale=0.15, init_alpha=2.0)
    observation = torch.randn(20000, 3)
    chain = torch.tanh(observation[:, :2])
    with set_exploration_type(ExplorationType.RANDOM):
        action = fixed_chain(noise)(TensorDict(observation=observation, batch_size=[20000]))
    residual = action["action"] - chain
    torch.testing.assert_close(residual.std(0), torch.full((2,), 0.3), atol=0.006, rtol=0)
    assert residual.mean(0).abs().max() < 0.01
    # uncorrelated across action dimensions
    assert abs(float(torch.corrcoef(residual.T)[0, 1])) < 0.03
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = fixed_chain(noise)(TensorDict(observation=observation, batch_size=[20000]))
    assert torch.equal(action["action"], chain)


@pytest.mark.parametrize("entropy, direction", [(-3.0, 1.0), (0.5, -1.0)])
def test_alpha_rises_below_the_target_entropy_and_falls_above(entropy, direction):
    """``∂L/∂ log α = Ĥ − H̄``; Adam's first step is ``lr · sign`` of it."""
    noise = EntropyRegulatedNoise(target_entropy=-1.8, init_alpha=3.0)
    optimizer = torch.optim.Adam([noise.log_alpha], lr=0.03)
    before = float(noise.log_alpha.detach())
    loss = noise.alpha_loss(torch.tensor([entropy, entropy]))
    loss.backward()
    assert float(noise.log_alpha.grad) == pytest.approx(entropy + 1.8)
    optimizer.step()
    assert float(noise.log_alpha.detach()) - before == pytest.approx(direction * 0.03, rel=1e-4)


def test_sampled_entropy_is_per_state_and_state_major():
    """States with noise stds 0.1, 0.2, 0.4 (``action = scale(s) · ε``): each estimate is
    its own Gaussian's closed form."""
    stds = torch.tensor([0.1, 0.2, 0.4])

    def policy(td):
        s = td["observation"]
        return td.set("action", s[:, :1] * torch.randn(s.shape[0], 2))

    torch.manual_seed(1)
    observation = stds[:, None].expand(3, 4).clone()
    estimate = sampled_entropy(policy, observation, num_samples=3000, num_components=1)
    exact = 2 * (0.5 * LOG_2PI_E + stds.log())
    torch.testing.assert_close(estimate, exact, atol=0.06, rtol=0)


def test_the_regulator_loop_settles_where_the_estimated_entropy_meets_the_target():
    """Closed loop on pure noise: ``Ĥ(α) = A/2 log(2πe) + A log(noise_scale · α)``, so the
    fixed point is ``α* = exp(H̄ / A − ½ log 2πe) / noise_scale``, from either side."""
    torch.manual_seed(2)
    target = dacer_target_entropy(2)  # -1.8
    alpha_star = math.exp(target / 2 - 0.5 * LOG_2PI_E) / 0.1
    for init_alpha in (0.2, 3.0):
        noise = EntropyRegulatedNoise(target, noise_scale=0.1, init_alpha=init_alpha)
        policy = TensorDictSequential(
            TensorDictModule(
                lambda s: torch.zeros(s.shape[0], 2), in_keys=["observation"], out_keys=["action"]
            ),
            noise,
        )
        optimizer = torch.optim.Adam([noise.log_alpha], lr=0.05)
        for _ in range(200):
            entropy = sampled_entropy(policy, torch.zeros(4, 1), 200, num_components=1)
            optimizer.zero_grad()
            noise.alpha_loss(entropy).backward()
            optimizer.step()
        assert float(noise.alpha) == pytest.approx(alpha_star, rel=0.1), init_alpha


def test_log_alpha_is_a_checkpointed_parameter_and_bad_settings_raise():
    noise = EntropyRegulatedNoise(target_entropy=-1.8, noise_scale=0.1, init_alpha=3.0)
    assert set(noise.state_dict()) == {"log_alpha", "noise_scale", "target_entropy"}
    assert [p for p in noise.parameters()] == [noise.log_alpha]
    with torch.no_grad():
        noise.log_alpha.fill_(0.0)
    other = EntropyRegulatedNoise(target_entropy=0.0)
    other.load_state_dict(noise.state_dict())
    assert float(other.alpha) == 1.0 and float(other.target_entropy) == pytest.approx(-1.8)
    assert "alpha=1" in repr(other)
    with pytest.raises(ValueError, match="init_alpha must be > 0"):
        EntropyRegulatedNoise(target_entropy=-1.8, init_alpha=0.0)
    with pytest.raises(ValueError, match="target_entropy must be finite"):
        EntropyRegulatedNoise(target_entropy=float("nan"))
    with pytest.raises(KeyError, match="EntropyRegulatedNoise .* reads 'action'"):
        noise(TensorDict(observation=torch.zeros(2, 3), batch_size=[2]))
