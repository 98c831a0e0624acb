"""Tests of ``PairedTrunk`` (``torchrl_dual/diffusion/_fast_path/paired_trunk.py``): two
denoiser trunks with different weights as one batched pass, rebuilt when either changes."""

from __future__ import annotations

import pytest
import torch

from torchrl_dual.diffusion._fast_path.paired_trunk import PairedTrunk
from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser


def _denoisers(depth: int = 2, seed: int = 0):
    torch.manual_seed(seed)
    return tuple(ResidualMLPDenoiser((3, 4), hidden=16, depth=depth) for _ in range(2))


def _check(trunk, first, second, hidden):
    with torch.no_grad():
        out = trunk(hidden)
        torch.testing.assert_close(out[0], first.trunk(hidden[0]))
        torch.testing.assert_close(out[1], second.trunk(hidden[1]))
    assert not torch.allclose(out[0], out[1])  # two different trunks, not one twice


@pytest.mark.parametrize("batch", [(), (7,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_one_batched_pass_equals_the_two_trunks(batch):
    first, second = _denoisers()
    hidden = torch.randn(2, *batch, 16)
    assert PairedTrunk(first, second)(hidden).shape == hidden.shape
    _check(PairedTrunk(first, second), first, second, hidden)


def test_the_stacked_weights_are_rebuilt_after_either_trunk_changes():
    first, second = _denoisers()
    trunk = PairedTrunk(first, second)
    hidden = torch.randn(2, 7, 16)
    _check(trunk, first, second, hidden)
    with torch.no_grad():  # in place, as an optimizer step: the version counters move
        second.blocks[1].net[3].weight.mul_(2.0)
    _check(trunk, first, second, hidden)
    with torch.no_grad():
        first.output_norm[0].bias.add_(1.0)
    _check(trunk, first, second, hidden)
    # replaced tensors (identity probe), as load_state_dict(..., assign=True) does
    first.load_state_dict(_denoisers(seed=1)[0].state_dict(), assign=True)
    _check(trunk, first, second, hidden)


def test_the_stacked_weights_follow_a_dtype_change():
    first, second = _denoisers()
    trunk = PairedTrunk(first, second)
    hidden = torch.randn(2, 7, 16)
    _check(trunk, first, second, hidden)
    first.double(), second.double()
    _check(trunk, first, second, hidden.double())


def test_the_stacked_weights_are_reused_while_nothing_changes():
    first, second = _denoisers()
    trunk = PairedTrunk(first, second)
    stacked = trunk._cache.get()
    trunk(torch.randn(2, 3, 16))
    assert trunk._cache.get() is stacked


def test_trunks_of_another_width_or_depth_are_rejected():
    first, _ = _denoisers()
    with pytest.raises(ValueError, match=r"same width and depth, got 16x2 and 16x1"):
        PairedTrunk(first, ResidualMLPDenoiser((3, 4), hidden=16, depth=1))
    with pytest.raises(ValueError, match=r"same width and depth, got 16x2 and 8x2"):
        PairedTrunk(first, ResidualMLPDenoiser((3, 4), hidden=8, depth=2))
