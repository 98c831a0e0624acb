"""Tests of the Laplace fit's numerics (``modules/laplace/_numerics.py``): the
eigendecomposition that never fails (its jitter retries and last resort, driven by an
``eigh`` that fails on purpose) and the evidence maximiser against its fixed point and
its bounds."""

from __future__ import annotations

import math

import pytest
import torch

from torchrl_dual.modules.laplace import _numerics
from torchrl_dual.modules.laplace._numerics import evidence_maximiser, psd_eigh

F64 = torch.float64


def _failing_eigh(failures: int, seen: list):
    real = torch.linalg.eigh

    def eigh(matrix):
        seen.append(matrix.clone())
        if len(seen) <= failures:
            raise RuntimeError("eigh did not converge (test)")
        return real(matrix)

    return eigh


def test_psd_eigh_matches_eigh_and_zeroes_round_off():
    A = torch.randn(5, 3, dtype=F64)
    G = A @ A.T  # rank 3 of 5: two eigenvalues are round-off
    g, U = psd_eigh(G)
    assert g.dtype == F64 and g.shape == (5,) and U.shape == (5, 5)
    assert (g[:2] == 0).all() and (g[2:] > 0).all()
    torch.testing.assert_close(U @ torch.diag(g) @ U.T, G)
    batch = torch.stack([G, 2 * G])
    gb, _ = psd_eigh(batch)
    torch.testing.assert_close(gb[1], 2 * g)


def test_psd_eigh_retries_with_a_growing_jitter_scaled_by_the_diagonal(monkeypatch):
    """Jitter 0, then 1e-12, then ×100 per failure, times max(max |diag G|, 1)."""
    seen: list = []
    monkeypatch.setattr(_numerics.torch.linalg, "eigh", _failing_eigh(3, seen))
    G = torch.diag(torch.tensor([4.0, 2.0, 0.5], dtype=F64))
    g, _ = psd_eigh(G)
    jitters = [float((m - G)[0, 0]) / 4.0 for m in seen]
    assert jitters == pytest.approx([0.0, 1e-12, 1e-10, 1e-8], rel=1e-3, abs=0)  # float64 round-off
    for matrix in seen:  # the jitter is on the diagonal only
        torch.testing.assert_close(
            matrix - torch.diag(matrix.diagonal()), torch.zeros(3, 3, dtype=F64)
        )
    torch.testing.assert_close(g, torch.tensor([0.5, 2.0, 4.0], dtype=F64) + 4e-8)


def test_psd_eigh_falls_back_to_zero_eigenvalues_after_eight_failures(monkeypatch):
    seen: list = []
    monkeypatch.setattr(_numerics.torch.linalg, "eigh", _failing_eigh(8, seen))
    G = torch.eye(3, dtype=F64).expand(2, 3, 3)
    g, U = psd_eigh(G)
    assert len(seen) == 8
    assert g.shape == (2, 3) and g.dtype == F64 and (g == 0).all()
    torch.testing.assert_close(U, torch.eye(3, dtype=F64).expand(2, 3, 3))


def test_the_evidence_maximiser_finds_mackay_s_fixed_point():
    h = torch.tensor([0.5, 3.0, 20.0], dtype=F64)
    sq = torch.tensor(0.7, dtype=F64)
    lam = evidence_maximiser(h, sq, (1e-8, 1e8))
    assert float((h / (h + lam)).sum()) == pytest.approx(lam * 0.7, rel=1e-9)


def test_the_evidence_maximiser_stops_at_its_bounds():
    h = torch.tensor([1.0, 4.0], dtype=F64)
    # slope ≤ 0 already at the lower bound: a huge ‖θ*‖² wants the smallest λ
    assert evidence_maximiser(h, torch.tensor(1e9, dtype=F64), (1e-3, 1e3)) == pytest.approx(1e-3)
    # slope ≥ 0 at the upper bound: a tiny ‖θ*‖² wants the largest λ
    assert evidence_maximiser(h, torch.tensor(1e-12, dtype=F64), (1e-3, 1e3)) == pytest.approx(1e3)
    # the root inside: bisection to 1e-12 in log λ
    lam = evidence_maximiser(h, torch.tensor(1.0, dtype=F64), (1e-3, 1e3))
    assert 1e-3 < lam < 1e3
    assert math.log(lam) == pytest.approx(math.log(float((h / (h + lam)).sum())), abs=1e-9)


def test_psd_eigh_scales_the_jitter_per_matrix_and_never_below_one(monkeypatch):
    """One failure: the retry adds ``1e-12 · max(max |diag G_k|, 1)`` to each ``G_k``."""
    seen: list = []
    monkeypatch.setattr(_numerics.torch.linalg, "eigh", _failing_eigh(1, seen))
    G = torch.stack(
        [
            torch.diag(torch.tensor([0.5, 0.25], dtype=F64)),  # max |diag| < 1: scale 1
            torch.diag(torch.tensor([1e4, 3.0], dtype=F64)),  # scale 1e4
        ]
    )
    psd_eigh(G)
    jitter = (seen[1] - G).diagonal(dim1=-2, dim2=-1)
    torch.testing.assert_close(
        jitter, torch.tensor([[1e-12, 1e-12], [1e-8, 1e-8]], dtype=F64), rtol=1e-3, atol=0
    )


def test_psd_eigh_judges_round_off_per_matrix_of_a_batch():
    """The threshold ``p·eps·max|g|`` is each matrix's own: a huge ``G_0`` does not zero
    the eigenvalues of a unit ``G_1``."""
    G = torch.stack([torch.diag(torch.tensor([1e16, 1.0], dtype=F64)), torch.eye(2, dtype=F64)])
    g, _ = psd_eigh(G)
    torch.testing.assert_close(g[1], torch.ones(2, dtype=F64))
    assert g[0].tolist() == [0.0, 1e16]  # 1 is round-off next to 1e16


def test_the_evidence_maximiser_returns_a_bound_exactly_when_clamped():
    h = torch.tensor([1.0, 4.0], dtype=F64)
    # slope(λ_max) = γ(1e3) − 1e3·1e-12 ∈ (0, 1): still clamped to the bound itself
    lam = evidence_maximiser(h, torch.tensor(1e-12, dtype=F64), (1e-3, 1e3))
    assert lam == pytest.approx(1e3, rel=1e-14, abs=0)


def test_the_evidence_maximiser_finds_a_fixed_point_below_one():
    h = torch.tensor([0.1, 0.3], dtype=F64)
    sq = torch.tensor(50.0, dtype=F64)
    lam = evidence_maximiser(h, sq, (1e-8, 1e8))
    assert lam < 1.0
    assert float((h / (h + lam)).sum()) == pytest.approx(lam * 50.0, rel=1e-9)
