"""The diffusion core against values computed here by hand (issue 31).

Each expected value is written out from the formulas, never by calling the code under
test: the schedules at interior times; Eq. 3's loss (v-parameterised) on a tiny batch;
the DDIM and DDPM samplers driven by the *exact* denoiser of a Gaussian data set, whose
output mean and variance follow from propagating the linear-Gaussian chain step by step;
and the distillation target (two teacher DDIM steps, then the one-step inversion) with
its truncated-SNR weight.
"""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from toy import identity_statistics

from torchrl_dual.diffusion import NoiseSchedule, TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.objectives import DiffusionPlannerLoss, DistillationLoss

LAYOUT = TrajectoryLayout(obs_dim=2, action_dim=1, horizon=2)  # windows [3, 3]
MU, STD = 0.7, 0.5  # the Gaussian data set: every window entry i.i.d. N(MU, STD²)


def alpha_sigma(kind: str, t: float) -> tuple[float, float]:
    """The schedules by hand: cosine ``α = cos(πt/2)``; linear ``log ᾱ = −(0.1 t +
    (20 − 0.1) t² / 2)``, ``α = √ᾱ``, ``σ = √(1 − ᾱ)``."""
    if kind == "cosine":
        return math.cos(math.pi * t / 2), math.sin(math.pi * t / 2)
    alpha_bar = math.exp(-(0.1 * t + 0.5 * 19.9 * t * t))
    return math.sqrt(alpha_bar), math.sqrt(1 - alpha_bar)


@pytest.mark.parametrize("kind", ["cosine", "linear"])
@pytest.mark.parametrize("t", [0.1, 0.3, 0.5, 0.77, 0.9])
def test_the_schedules_match_their_formulas_at_interior_times(kind, t):
    alpha, sigma = NoiseSchedule(kind)(torch.tensor([t], dtype=torch.float64))
    want = alpha_sigma(kind, t)
    assert (alpha.item(), sigma.item()) == pytest.approx(want, rel=1e-9, abs=1e-12)
    snr = NoiseSchedule(kind).snr(torch.tensor([t], dtype=torch.float64)).item()
    assert snr == pytest.approx(want[0] ** 2 / want[1] ** 2, rel=1e-9)


class GaussianOracle(nn.Module):
    """The exact ``v̂`` for data i.i.d. ``N(MU, STD²)`` per entry: ``x̂ = E[x | z_t] =
    MU + k (z − α MU)``, ``k = α STD² / (α² STD² + σ²)``, and ``v̂ = (α z − x̂) / σ``."""

    def __init__(self, kind: str) -> None:
        super().__init__()
        self.kind = kind
        self.register_buffer("unused", torch.zeros(()))  # a module with state, as a denoiser

    def forward(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        alpha, sigma = NoiseSchedule(self.kind)(t.to(z.dtype))
        alpha, sigma = alpha[..., None, None], sigma[..., None, None]
        x_hat = MU + alpha * STD**2 / (alpha**2 * STD**2 + sigma**2) * (z - alpha * MU)
        return (alpha * z - x_hat) / sigma


def oracle_model(kind: str, num_steps: int) -> TrajectoryDiffusion:
    return TrajectoryDiffusion(
        LAYOUT, GaussianOracle(kind), schedule=kind, num_steps=num_steps
    ).double()


def chain_moments(kind: str, num_steps: int, sampler: str) -> tuple[float, float]:
    """Mean and variance of one entry after the sampler, by propagating ``z ~ N(m, v)``
    through each step, which is affine in ``z`` plus Gaussian noise for this oracle:
    ``x̂ = a z + b``; DDIM ``z_s = α_s x̂ + σ_s (z − α_t x̂) / σ_t``; DDPM
    ``z_s ~ N((α_ts σ_s² z + α_s v_ts x̂) / σ_t², v_ts σ_s² / σ_t²)`` with
    ``α_ts = α_t / α_s``, ``v_ts = σ_t² − α_ts² σ_s²``; the last step returns ``x̂``."""
    m, v = 0.0, 1.0
    times = [1 - i / num_steps for i in range(num_steps + 1)]
    for n, (t, s) in enumerate(zip(times[:-1], times[1:], strict=True)):
        at, st = alpha_sigma(kind, t)
        k = at * STD**2 / (at**2 * STD**2 + st**2)
        a, b = k, MU - k * at * MU  # x̂ = a z + b
        if n == num_steps - 1:  # the last step: x̂ itself
            return a * m + b, a * a * v
        as_, ss = alpha_sigma(kind, s)
        if sampler == "ddim":
            gain = as_ * a + ss * (1 - at * a) / st
            shift = as_ * b - ss * at * b / st
            m, v = gain * m + shift, gain * gain * v
        else:
            ats = at / as_
            vts = st**2 - ats**2 * ss**2
            gain = (ats * ss**2 + as_ * vts * a) / st**2
            m = gain * m + as_ * vts * b / st**2
            v = gain * gain * v + vts * ss**2 / st**2
    raise AssertionError("unreachable")


def sample(kind: str, num_steps: int, sampler: str, batch: int = 20000) -> torch.Tensor:
    model = oracle_model(kind, num_steps)
    cond = torch.zeros(batch, *LAYOUT.window_shape, dtype=torch.float64)
    mask = torch.zeros(LAYOUT.window_shape, dtype=torch.bool)
    generator = torch.Generator().manual_seed(0)
    return model.sample(cond, mask, sampler=sampler, generator=generator).flatten()


@pytest.mark.parametrize("kind", ["cosine", "linear"])
@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_the_samplers_with_the_exact_denoiser_have_the_chain_s_moments(kind, sampler):
    """20000 windows (180000 entries) of the 32-step sampler: mean and variance within 4
    standard errors of the hand-propagated chain (whose variance is 0.18-0.23 here, not
    yet the data's 0.25: 32 steps of an exact denoiser still carry a discretization
    error, which the next test shows shrinking)."""
    out = sample(kind, 32, sampler)
    mean, var = chain_moments(kind, 32, sampler)
    n = out.numel()
    assert out.mean().item() == pytest.approx(mean, abs=4 * math.sqrt(var / n))
    assert out.var().item() == pytest.approx(var, abs=4 * var * math.sqrt(2 / n))


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_with_many_exact_steps_the_sampler_maps_noise_to_the_data_distribution(sampler):
    out = sample("cosine", 512, sampler, batch=4000)
    assert out.mean().item() == pytest.approx(MU, abs=0.01)
    assert out.var().item() == pytest.approx(STD**2, abs=0.01)


def test_the_one_step_sampler_returns_the_oracle_s_x_hat_at_t_1():
    model = oracle_model("cosine", 1)
    noise = torch.randn(4, *LAYOUT.window_shape, dtype=torch.float64)
    mask = torch.zeros(LAYOUT.window_shape, dtype=torch.bool)
    out = model.sample(torch.zeros_like(noise), mask, noise=noise)
    torch.testing.assert_close(out, torch.full_like(out, MU))  # α_1 = 0: x̂ = E[x] = MU


def windows(batch: int, seed: int) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(batch, LAYOUT.length, LAYOUT.obs_dim, generator=g)
    act = torch.randn(batch, LAYOUT.length, LAYOUT.action_dim, generator=g)
    mask = LAYOUT.condition_mask("s0").expand(batch, *LAYOUT.window_shape)
    return TensorDict(
        {"observation": obs, "action": act, "condition_mask": mask}, [batch, LAYOUT.length]
    )


def test_eq3_loss_is_the_masked_mean_v_error_computed_by_hand():
    torch.manual_seed(1)
    model = TrajectoryDiffusion(LAYOUT, hidden=16, depth=1)
    identity_statistics(model.normalizer)
    data = windows(6, seed=2)
    loss_fn = DiffusionPlannerLoss(model, reduction="none")
    torch.manual_seed(3)
    out = loss_fn(data)
    got = out["loss_diffusion"]
    torch.manual_seed(3)  # the loss draws t ~ U(0, 1) per window, then ε ~ N(0, I)
    t = torch.rand(6)
    x0 = torch.cat([data["observation"], data["action"]], -1)  # identity normalizer
    eps = torch.randn_like(x0)
    alpha, sigma = (
        torch.cos(math.pi * t / 2)[:, None, None],
        torch.sin(math.pi * t / 2)[:, None, None],
    )
    mask = data["condition_mask"]
    z = torch.where(mask, x0, alpha * x0 + sigma * eps)
    v_hat = model.denoiser(z, t, mask)
    error = (v_hat - (alpha * eps - sigma * x0)) ** 2
    free = (~mask).float()
    want = (error * free).sum((-2, -1)) / free.sum((-2, -1))
    torch.testing.assert_close(got, want)
    # the diagnostic: x̂ = α z − σ v̂ on the generated entries, its squared error's mean
    x_hat = alpha * z - sigma * v_hat
    x0_error = (((x_hat - x0) ** 2 * free).sum((-2, -1)) / free.sum((-2, -1))).mean()
    torch.testing.assert_close(out["x0_error"], x0_error)


def test_the_distillation_target_and_weight_computed_by_hand():
    """Teacher: the Gaussian oracle with N = 8; student: a small network with N = 4. The
    target is two teacher DDIM steps t → t − 1/8 → s = t − 1/4 written out, then
    ``x̃ = (z_s − (σ_s/σ_t) z_t) / (α_s − (σ_s/σ_t) α_t)``; the weight ``max(α_t²/σ_t², 1)``."""
    teacher = TrajectoryDiffusion(LAYOUT, GaussianOracle("cosine"), num_steps=8)
    torch.manual_seed(4)
    student = TrajectoryDiffusion(LAYOUT, num_steps=4, hidden=16, depth=1)
    identity_statistics(student.normalizer)
    data = windows(8, seed=5)
    loss_fn = DistillationLoss(student, teacher, reduction="none")
    torch.manual_seed(6)
    out = loss_fn(data)
    got = out["loss_distillation"]

    torch.manual_seed(6)  # the loss draws i ∈ {1, .., 4} per window, then ε ~ N(0, I)
    i = torch.randint(1, 5, (8,)).double()
    x0 = torch.cat([data["observation"], data["action"]], -1).double()
    eps = torch.randn_like(x0.float()).double()
    mask = data["condition_mask"]

    def scales(time):
        return torch.cos(math.pi * time / 2)[:, None, None], torch.sin(math.pi * time / 2)[
            :, None, None
        ]

    def oracle_x_hat(z, time):
        a, s = scales(time)
        return MU + a * STD**2 / (a**2 * STD**2 + s**2) * (z - a * MU)

    def ddim(z, t_from, t_to):  # with the known entries kept clean
        x_hat = torch.where(mask, x0, oracle_x_hat(z, t_from))
        a_t, s_t = scales(t_from)
        a_s, s_s = scales(t_to)
        return torch.where(mask, x0, a_s * x_hat + s_s * (z - a_t * x_hat) / s_t)

    t, mid, s = i / 4, (i - 0.5) / 4, (i - 1) / 4
    a_t, s_t = scales(t)
    z_t = torch.where(mask, x0, a_t * x0 + s_t * eps)
    z_s = ddim(ddim(z_t, t, mid), mid, s)
    a_s, s_s = scales(s)
    target = torch.where(mask, x0, (z_s - s_s / s_t * z_t) / (a_s - s_s / s_t * a_t))
    v_hat = student.denoiser(z_t.float(), t.float(), mask).double()
    x_student = torch.where(mask, x0, a_t * z_t - s_t * v_hat)
    weight = (a_t**2 / s_t**2).clamp(min=1.0)
    free = (~mask).double()
    want = (weight * (x_student - target) ** 2 * free).sum((-2, -1)) / free.sum((-2, -1))
    torch.testing.assert_close(got.double(), want, rtol=1e-4, atol=1e-6)
    assert (weight.flatten() > 5).any() and (weight.flatten() == 1).any()  # both branches
    gap = (((x_student - target) ** 2 * free).sum((-2, -1)) / free.sum((-2, -1))).mean()
    torch.testing.assert_close(out["target_gap"].double(), gap, rtol=1e-4, atol=1e-6)
