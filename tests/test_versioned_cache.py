"""Tests of ``VersionedCache`` (``torchrl_dual/_versioned_cache.py``):
a derived value is recomputed exactly when one of its source tensors changes."""

from __future__ import annotations

import torch

from torchrl_dual._versioned_cache import VersionedCache


class _Counted:
    """``compute`` of a cache over ``holder``'s tensors: their sum, counting the calls."""

    def __init__(self, holder: dict[str, torch.Tensor]) -> None:
        self.holder = holder
        self.calls = 0

    def __call__(self) -> torch.Tensor:
        self.calls += 1
        return sum(tensor.sum() for tensor in self.holder.values())


def _cache(holder, probe=None):
    compute = _Counted(holder)
    return VersionedCache(lambda: list(holder.values()), compute, probe), compute


def test_the_value_is_computed_once_until_a_source_is_modified_in_place():
    holder = {"a": torch.ones(3), "b": torch.ones(2)}
    cache, compute = _cache(holder)
    first = cache.get()
    assert cache.get() is first and compute.calls == 1
    holder["b"].mul_(4.0)  # bumps b's version counter
    assert cache.get() == 3.0 + 8.0 and compute.calls == 2
    assert cache.get() == 11.0 and compute.calls == 2


def test_a_replaced_source_tensor_is_noticed_by_identity_even_at_the_same_version():
    holder = {"a": torch.ones(3)}
    cache, compute = _cache(holder)
    cache.get()
    replacement = torch.full((3,), 2.0)
    assert replacement._version == holder["a"]._version  # the version alone cannot tell
    holder["a"] = replacement  # what .to() or load_state_dict(assign=True) do
    assert cache.get() == 6.0 and compute.calls == 2


def test_a_parameter_converted_in_place_by_module_to_is_noticed_by_its_storage():
    layer = torch.nn.Linear(2, 2)
    weight = layer.weight
    cache = VersionedCache(lambda: [layer.weight], lambda: layer.weight.sum())
    assert cache.get().dtype == torch.float32
    version = weight._version
    layer.double()  # same Parameter object, same version counter, new storage
    assert layer.weight is weight and weight._version == version
    assert cache.get().dtype == torch.float64


def test_with_a_probe_only_the_probed_tensors_are_checked_by_identity():
    holder = {"a": torch.ones(3), "b": torch.ones(2)}
    probed = {"a": holder["a"]}
    cache, compute = _cache(holder, probe=lambda: list(probed.values()))
    cache.get()
    holder["b"] = torch.full((2,), 5.0)  # replaced but not probed: the documented blind spot
    assert cache.get() == 5.0 and compute.calls == 1
    probed["a"] = holder["a"] = torch.full((3,), 2.0)  # the probe sees the replacement
    assert cache.get() == 6.0 + 10.0 and compute.calls == 2
    holder["b"].add_(1.0)  # an in-place edit of any source is still noticed
    assert cache.get() == 6.0 + 12.0 and compute.calls == 3


def test_a_probe_of_another_length_forces_a_rebuild():
    holder = {"a": torch.ones(1)}
    probes = [holder["a"]]
    cache = VersionedCache(lambda: list(holder.values()), lambda: holder["a"] * 1, lambda: probes)
    first = cache.get()
    probes.append(torch.zeros(1))
    assert cache.get() is not first


def test_the_value_is_computed_without_autograd():
    weight = torch.nn.Parameter(torch.ones(3))
    cache = VersionedCache(lambda: [weight], lambda: weight * 2.0)
    value = cache.get()
    assert not value.requires_grad and value.grad_fn is None
    torch.testing.assert_close(value, torch.full((3,), 2.0))
