"""Eq. (8) through a squash: the per-output generalised Gauss-Newton posterior of
``LastLayerLaplace(per_output_jacobian=True)`` and the Gaussian IQL actor that uses it."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor
from torchrl_dual.modules.actors.last_layer_actor import TanhSquash
from torchrl_dual.modules.laplace.last_layer_laplace import LastLayerLaplace
from torchrl_dual.recipe.algos.iql import make_iql_actor
from torchrl_dual.recipe.settings.baselines import MLPActorSettings

F64 = torch.float64


def _squashed_problem(n: int = 40, d: int = 3, out: int = 2, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    phi = torch.randn(n, d, generator=g, dtype=F64)
    weights = torch.rand(n, generator=g, dtype=F64) + 0.1
    theta = 0.7 * torch.randn(out, d + 1, generator=g, dtype=F64)
    squash = TanhSquash(torch.tensor([-2.0, 0.0]), torch.tensor([1.0, 3.0])).double()
    sigma2 = torch.tensor([0.3, 0.05], dtype=F64)
    return phi, weights, theta, squash, sigma2


def test_per_output_precision_is_the_exact_hessian_at_zero_residual() -> None:
    """With data on the MAP's squashed mean the residuals vanish and the Gauss-Newton
    matrix is the Hessian of ``Σ_i w_i Σ_j (a_ij − c_j(θ_jᵀφ̃_i))²/(2σ_j²) + λ/2 ‖θ‖²``."""
    phi, weights, theta_star, squash, sigma2 = _squashed_problem()
    phi1 = torch.cat([phi, torch.ones(len(phi), 1, dtype=F64)], dim=1)
    targets = squash(phi1 @ theta_star.T)  # zero residual at θ*
    lam = 0.37

    def loss(theta_flat: torch.Tensor) -> torch.Tensor:
        theta = theta_flat.view_as(theta_star)
        residual = targets - squash(phi1 @ theta.T)
        # the Laplace normalises the weights to mean 1
        w = weights * len(weights) / weights.sum()
        nll = (w[:, None] * residual.square() / (2 * sigma2)).sum()
        return nll + 0.5 * lam * theta_flat.square().sum()

    hessian = torch.autograd.functional.hessian(loss, theta_star.flatten())
    la = LastLayerLaplace(3, 2, prior_precision=lam, per_output_jacobian=True)
    jacobian = squash.derivative(phi1 @ theta_star.T)
    la.accumulate(phi, weights, jacobian)
    la.fit(theta_star[:, :-1], theta_star[:, -1], sigma2)
    precision = la.posterior_precision()
    p = phi1.shape[1]
    for j in range(2):
        block = hessian[j * p : (j + 1) * p, j * p : (j + 1) * p]
        torch.testing.assert_close(precision[j], block, rtol=1e-10, atol=1e-10)
    # block diagonal: outputs do not couple
    assert hessian[:p, p:].abs().max() < 1e-12


def test_constant_jacobian_equals_the_shared_gram_with_rescaled_noise() -> None:
    phi, weights, theta, _, sigma2 = _squashed_problem()
    r = torch.tensor([1.5, 0.5], dtype=F64)
    per_output = LastLayerLaplace(3, 2, per_output_jacobian=True)
    per_output.accumulate(phi, weights, r.expand(len(phi), 2))
    per_output.fit(theta[:, :-1], theta[:, -1], sigma2)
    shared = LastLayerLaplace(3, 2)
    shared.accumulate(phi, weights)
    shared.fit(theta[:, :-1], theta[:, -1], sigma2 / r.square())
    torch.testing.assert_close(per_output.prior_precision, shared.prior_precision)
    torch.testing.assert_close(per_output.posterior_covariance(), shared.posterior_covariance())
    torch.testing.assert_close(per_output.predictive_variance(phi), shared.predictive_variance(phi))


def test_per_output_samples_and_predictive_variance_follow_the_covariance() -> None:
    phi, weights, theta, squash, sigma2 = _squashed_problem()
    phi1 = torch.cat([phi, torch.ones(len(phi), 1, dtype=F64)], dim=1)
    la = LastLayerLaplace(3, 2, prior_precision=0.5, per_output_jacobian=True)
    la.accumulate(phi, weights, squash.derivative(phi1 @ theta.T))
    la.fit(theta[:, :-1], theta[:, -1], sigma2)
    covariance = la.posterior_covariance()
    torch.testing.assert_close(
        covariance @ la.posterior_precision(), torch.eye(4, dtype=F64).expand(2, 4, 4)
    )
    expected = torch.einsum("np,opq,nq->no", phi1, covariance, phi1)
    torch.testing.assert_close(la.predictive_variance(phi), expected)
    draws = la.sample(100_000, generator=torch.Generator().manual_seed(1), dtype=F64)
    centred = draws - theta
    empirical = torch.einsum("mop,moq->opq", centred, centred) / len(draws)
    torch.testing.assert_close(
        empirical, covariance, rtol=0.05, atol=0.05 * covariance.abs().max().item()
    )


def test_per_output_state_dict_round_trips() -> None:
    phi, weights, theta, squash, sigma2 = _squashed_problem()
    la = LastLayerLaplace(3, 2, per_output_jacobian=True)
    la.accumulate(phi, weights, torch.rand(len(phi), 2, dtype=F64))
    la.fit(theta[:, :-1], theta[:, -1], sigma2)
    copy = LastLayerLaplace(3, 2, per_output_jacobian=True)
    copy.load_state_dict(la.state_dict())
    torch.testing.assert_close(copy.predictive_variance(phi), la.predictive_variance(phi))
    assert la.G_raw.shape == (2, 4, 4) and la.eigenvectors.shape == (2, 4, 4)


def test_jacobian_argument_errors_name_the_fix() -> None:
    phi = torch.randn(5, 3)
    with pytest.raises(ValueError, match="per_output_jacobian=True: pass jacobian"):
        LastLayerLaplace(3, 2, per_output_jacobian=True).accumulate(phi)
    with pytest.raises(ValueError, match="jacobian must have shape \\[5, 2\\]"):
        LastLayerLaplace(3, 2, per_output_jacobian=True).accumulate(phi, None, torch.ones(5, 3))
    with pytest.raises(ValueError, match="build it with per_output_jacobian=True"):
        LastLayerLaplace(3, 2).accumulate(phi, None, torch.ones(5, 2))


def _gaussian_iql_actor(obs_dim: int = 3):
    settings = MLPActorSettings(hidden=16, depth=2, lr=3e-4)
    spec = Bounded(torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0]), shape=(2,))
    return make_iql_actor(settings, obs_dim, spec, distribution="gaussian")


def test_from_gaussian_iql_actor_shares_the_mean_and_squash() -> None:
    actor = _gaussian_iql_actor()
    head_actor = LinearHeadActor.from_actor(actor)
    net = actor.module[0].module
    assert head_actor.noise_after_squash and head_actor.squash is net[1]
    assert head_actor.head is net[0][-1]
    obs = torch.randn(7, 3)
    loc = actor(TensorDict(observation=obs, batch_size=[7]))["loc"]
    torch.testing.assert_close(head_actor(obs), loc)


def test_ensemble_fit_of_the_gaussian_actor_weighs_by_the_tanh_jacobian() -> None:
    """The ensemble hands the Laplace ``J_ij = r_j (1 − tanh²(u_ij))`` and ``σ = σ̄`` (action
    units), so its Gram matrices are ``Σ_i w_i J_ij² φ̃_i φ̃_iᵀ`` computed independently."""
    torch.manual_seed(0)
    head_actor = LinearHeadActor.from_actor(_gaussian_iql_actor())
    ensemble = LaplaceEnsembleActor(head_actor, num_samples=3, prior_precision=1.0)
    obs, weights = torch.randn(50, 3), torch.rand(50) + 0.5
    ensemble.fit_laplace(
        [TensorDict(observation=obs, w=weights, batch_size=[50])], weight_fn=lambda b: b["w"]
    )
    with torch.no_grad():
        phi = head_actor.trunk(obs).double()
        u = head_actor.head(head_actor.trunk(obs)).double()
    half_range = torch.tensor([1.0, 1.0], dtype=F64)
    jacobian = half_range * (1 - torch.tanh(u).square())
    phi1 = torch.cat([phi, torch.ones(50, 1, dtype=F64)], dim=1)
    w = weights.double() * 50 / weights.double().sum()
    expected = torch.einsum("n,no,np,nq->opq", w, jacobian.square(), phi1, phi1)
    torch.testing.assert_close(ensemble.laplace.gram(), expected, rtol=1e-5, atol=1e-6)
    sigma2 = head_actor.std.double().square()
    torch.testing.assert_close(ensemble.laplace.noise_variance, sigma2.detach())
    # the ensemble acts through the squash: every member's action lies in the box
    members = ensemble.member_actions(torch.randn(20, 3) * 5)
    assert (members[..., 1] >= 0).all() and (members[..., 1] <= 2).all()
