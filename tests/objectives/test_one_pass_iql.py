"""``OnePassIQLLoss``: TorchRL's IQL losses, bitwise, with the target Q and V(s) once."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.objectives import IQLLoss
from toy import observation_action_batch, tiny_iql_loss

from torchrl_dual.objectives import OnePassIQLLoss

OBS, ACT, B = 3, 2, 16
TERMS = ("loss_actor", "loss_qvalue", "loss_value")


def _batch(seed: int = 0) -> TensorDict:
    batch = observation_action_batch(B, OBS, ACT, seed=seed)
    gen = torch.Generator().manual_seed(seed + 1)
    batch["next"] = TensorDict(
        {
            "observation": torch.randn(B, OBS, generator=gen),
            "reward": torch.randn(B, 1, generator=gen),
            "done": torch.rand(B, 1, generator=gen) < 0.2,
        },
        [B],
    )
    batch["next", "terminated"] = batch["next", "done"].clone()
    return batch


def _pair(**kwargs) -> tuple[IQLLoss, OnePassIQLLoss]:
    reference = tiny_iql_loss(OBS, ACT, seed=3, loss_function="l2", temperature=3.0, **kwargs)
    one_pass = tiny_iql_loss(
        OBS,
        ACT,
        seed=3,
        loss_class=OnePassIQLLoss,
        loss_function="l2",
        temperature=3.0,
        **kwargs,
    )
    # the target Q networks away from the online ones, as after training
    for loss in (reference, one_pass):
        with torch.no_grad():
            loss.target_qvalue_network_params.apply(lambda p: p.add_(0.05))
    return reference, one_pass


def _grads(loss: IQLLoss) -> dict[str, torch.Tensor | None]:
    return {name: p.grad for name, p in loss.named_parameters()}


def test_terms_and_gradients_are_torchrl_bitwise():
    reference, one_pass = _pair()
    batch = _batch()
    expected = {
        "loss_actor": reference.actor_loss(batch.clone())[0],
        "loss_qvalue": reference.qvalue_loss(batch.clone())[0],
        "loss_value": reference.value_loss(batch.clone())[0],
    }
    got = one_pass.terms(batch.clone())
    assert set(got) == set(TERMS)
    for name in TERMS:
        assert torch.equal(got[name], expected[name]), name
    sum(expected.values()).backward()
    sum(got.values()).backward()
    ref_grads, got_grads = _grads(reference), _grads(one_pass)
    assert ref_grads.keys() == got_grads.keys()
    for name, grad in ref_grads.items():
        if grad is None:
            assert got_grads[name] is None, name
        else:
            assert torch.equal(got_grads[name], grad), name


def test_training_steps_stay_bitwise_equal():
    """Ten Adam steps on the summed terms of each loss end on the same weights."""
    reference, one_pass = _pair()
    optimizers = [torch.optim.Adam(loss.parameters(), lr=1e-2) for loss in (reference, one_pass)]
    for step in range(10):
        batch = _batch(seed=step)
        ref_terms = [
            reference.qvalue_loss(batch)[0],
            reference.value_loss(batch)[0],
            reference.actor_loss(batch)[0],
        ]
        losses = (sum(ref_terms), sum(one_pass.terms(batch.clone()).values()))
        for optimizer, loss in zip(optimizers, losses, strict=True):
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    ref_state, state = reference.state_dict(), one_pass.state_dict()
    assert ref_state.keys() == state.keys()
    assert all(torch.equal(ref_state[k], state[k]) for k in ref_state)


def test_actor_gradient_never_reaches_v_nor_q():
    _, one_pass = _pair()
    one_pass.terms(_batch())["loss_actor"].backward()
    for name, p in one_pass.named_parameters():
        if name.startswith(("value_network_params", "qvalue_network_params")):
            assert p.grad is None or not p.grad.any(), name
    assert any(
        p.grad is not None and p.grad.any()
        for name, p in one_pass.named_parameters()
        if name.startswith("actor_network_params")
    )


def test_v_and_target_q_run_once_each():
    """TorchRL's three methods evaluate V three times (V(s) twice, V(s') once) and the Q
    ensemble three times (Q in the TD loss, the target Q twice); the one pass evaluates V
    twice (V(s), V(s')) and the Q ensemble twice (the target Q once)."""

    def count_calls(loss: IQLLoss) -> tuple[int, int]:
        calls = {"value": 0, "q": 0}
        hook = loss.value_network.register_forward_hook(
            lambda *_: calls.__setitem__("value", calls["value"] + 1)
        )
        q_call = loss._vmap_qvalue_networkN0  # the Q ensemble's one call (vmap or EnsembleMLP)

        def counted(*args):
            calls["q"] += 1
            return q_call(*args)

        loss._vmap_qvalue_networkN0 = counted
        try:
            if isinstance(loss, OnePassIQLLoss):
                loss.terms(_batch())
            else:
                for method in (loss.qvalue_loss, loss.value_loss, loss.actor_loss):
                    method(_batch())
        finally:
            hook.remove()
            loss._vmap_qvalue_networkN0 = q_call
        return calls["value"], calls["q"]

    reference, one_pass = _pair()
    ref_value, ref_q = count_calls(reference)
    value, q = count_calls(one_pass)
    assert (ref_value, value) == (3, 2)
    assert (ref_q, q) == (3, 2)


@pytest.mark.parametrize("reduction", ["mean", "none"])
def test_forward_matches_torchrl_forward(reduction):
    extra = {"scalar_output_mode": "exclude"} if reduction == "none" else {}
    reference, one_pass = _pair(reduction=reduction, **extra)
    ref_batch, batch = _batch(), _batch()
    expected, got = reference(ref_batch), one_pass(batch)
    assert set(got.keys()) == set(expected.keys())
    for key in expected.keys():
        assert torch.equal(got[key], expected[key]), key
    assert torch.equal(batch["td_error"], ref_batch["td_error"])
    assert torch.equal(batch["_log_prob"], ref_batch["_log_prob"])


def test_log_prob_written_detached():
    _, one_pass = _pair()
    batch = _batch()
    one_pass.terms(batch)
    assert not batch[one_pass.tensor_keys.log_prob].requires_grad
