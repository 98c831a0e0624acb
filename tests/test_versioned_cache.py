"""Tests of ``VersionedCache`` (``torchrl_dual/_versioned_cache.py``):
a derived value is recomputed exactly when one of its modules' tensors changes."""

from __future__ import annotations

import copy

import pytest
import torch
from torch import nn
from torch.optim.optimizer import register_optimizer_step_post_hook

import torchrl_dual._versioned_cache as versioned_cache
from torchrl_dual._versioned_cache import VersionedCache


class _Holder(nn.Module):
    """A parameter and a buffer, the two kinds of source tensor."""

    def __init__(self) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(3))
        self.register_buffer("scale", torch.ones(2))


class _Counted:
    """``compute`` of a cache over a ``_Holder``: the sum of its tensors, counting calls."""

    def __init__(self, holder: _Holder) -> None:
        self.holder = holder
        self.calls = 0

    def __call__(self) -> torch.Tensor:
        self.calls += 1
        return self.holder.weight.sum() + self.holder.scale.sum()


def _cache() -> tuple[_Holder, VersionedCache, _Counted]:
    holder = _Holder()
    compute = _Counted(holder)
    return holder, VersionedCache([holder], compute), compute


def test_the_value_is_computed_once_until_a_source_is_modified_in_place():
    holder, cache, compute = _cache()
    first = cache.get()
    assert cache.get() is first and compute.calls == 1
    holder.scale.mul_(4.0)  # a buffer: bumps its version counter
    assert cache.get() == 3.0 + 8.0 and compute.calls == 2
    assert cache.get() == 11.0 and compute.calls == 2
    with torch.no_grad():
        holder.weight.add_(1.0)  # a parameter, as an optimizer step does
    assert cache.get() == 6.0 + 8.0 and compute.calls == 3


def test_a_replaced_source_tensor_is_noticed_by_identity_even_at_the_same_version():
    holder, cache, compute = _cache()
    cache.get()
    replacement = nn.Parameter(torch.full((3,), 2.0))
    assert replacement._version == holder.weight._version  # the version alone cannot tell
    holder.weight = replacement  # what load_state_dict(assign=True) does
    assert cache.get() == 6.0 + 2.0 and compute.calls == 2
    holder.load_state_dict({"weight": torch.zeros(3), "scale": torch.zeros(2)}, assign=True)
    assert cache.get() == 0.0 and compute.calls == 3


def test_a_parameter_converted_in_place_by_module_to_is_noticed_by_its_storage():
    layer = nn.Linear(2, 2)
    weight = layer.weight
    cache = VersionedCache([layer], lambda: layer.weight.sum())
    assert cache.get().dtype == torch.float32
    version = weight._version
    layer.double()  # same Parameter object, same version counter, new storage
    assert layer.weight is weight and weight._version == version
    assert cache.get().dtype == torch.float64


def test_only_the_listed_modules_are_watched_not_their_submodules():
    outer = nn.Sequential(nn.Linear(2, 2))
    calls = []
    cache = VersionedCache([outer], lambda: calls.append(1) or outer[0].weight.sum())
    cache.get()
    with torch.no_grad():
        outer[0].weight.add_(1.0)  # a submodule's tensor: the documented blind spot
    cache.get()
    assert len(calls) == 1
    watched = VersionedCache([outer[0]], lambda: calls.append(1) or outer[0].weight.sum())
    watched.get()
    with torch.no_grad():
        outer[0].weight.add_(1.0)
    watched.get()
    assert len(calls) == 3


def test_a_deep_copy_recomputes_from_its_own_tensors():
    """A policy copied for a collector carries its cache along: the copy must not serve
    the original's value once either side changes."""
    holder, cache, _ = _cache()
    cache.get()
    twin_holder, twin_cache = copy.deepcopy((holder, cache))
    with torch.no_grad():
        twin_holder.weight.mul_(3.0)
    assert twin_cache.get() == 9.0 + 2.0
    assert cache.get() == 3.0 + 2.0


def test_the_value_is_computed_without_autograd():
    holder, cache, _ = _cache()
    value = cache.get()
    assert not value.requires_grad and value.grad_fn is None
    torch.testing.assert_close(value, torch.tensor(5.0))


def test_a_tensor_instead_of_a_module_is_refused_with_the_fix():
    with pytest.raises(TypeError, match="pass the module that holds the tensor"):
        VersionedCache([torch.ones(2)], lambda: None)


@pytest.fixture
def without_the_fused_step_hook():
    versioned_cache._FUSED_STEP_HOOK.remove()
    yield
    versioned_cache._FUSED_STEP_HOOK = register_optimizer_step_post_hook(
        versioned_cache.mark_fused_steps
    )


def test_pytorch_s_fused_adam_still_leaves_the_version_counters_alone(
    without_the_fused_step_hook,
):
    """The reason for the hook. When this fails, PyTorch moves the counters itself:
    delete ``mark_fused_steps`` and its registration."""
    layer = nn.Linear(2, 2)
    optimizer = torch.optim.Adam(layer.parameters(), fused=True)
    layer(torch.ones(1, 2)).sum().backward()
    before = layer.weight._version
    optimizer.step()
    assert layer.weight._version == before


@pytest.mark.parametrize("kind", ["fused", "foreach", "for-loop"])
def test_a_cache_follows_every_optimizer_step_fused_or_not(kind):
    layer = nn.Linear(3, 2)
    options = {"fused": {"fused": True}, "foreach": {"foreach": True}, "for-loop": {}}
    optimizer = torch.optim.Adam(layer.parameters(), lr=0.1, **options[kind])
    cache = VersionedCache([layer], lambda: layer.weight.clone())
    for _ in range(3):
        layer(torch.ones(4, 3)).square().sum().backward()
        optimizer.step()
        optimizer.zero_grad()
        torch.testing.assert_close(cache.get(), layer.weight.detach(), rtol=0, atol=0)
