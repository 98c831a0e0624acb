"""Tests of ``PlannerActor`` (``torchrl_dual/modules/actors/planner_actor.py``), DUAL's actor:
``μ(s) = τ_{a_0}`` of the one-step planner (Eq. 5, Eq. 7), its exact fast path and the
transition query it answers in the same pass (Eq. 10)."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import (
    WEIGHT_CHANGES,
    apply_weight_change,
    assert_all_close,
    fine_tuned,
    plain_prediction,
    transition_inputs,
)

from torchrl_dual.diffusion import TrajectoryDiffusion
from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    LastLayerActor,
    PlannerActor,
    PlannerPolicy,
    PlannerSampler,
    TransitionModel,
)
from torchrl_dual.objectives import WeightedMAPActorLoss

TRANSITIONS = ("shared", "frozen-copy")
CHANGE_CASES = [
    pytest.param(change, kind, id=f"{change}-{kind}")
    for kind in TRANSITIONS
    for change in WEIGHT_CHANGES
]


def _with_head(actor, weight: torch.Tensor, bias: torch.Tensor):
    actor = copy.deepcopy(actor)
    with torch.no_grad():
        actor.head.weight.copy_(weight)
        actor.head.bias.copy_(bias)
    return actor


def _transition(actor: PlannerActor, kind: str) -> TransitionModel:
    """The actor's own planner (Algorithm 1's single θ), or a frozen, different copy."""
    if kind == "shared":
        return TransitionModel(actor.model, frozen=False)
    return TransitionModel(fine_tuned(actor.model))


def _generic(actor, transition_model, *inputs):
    """The two plain calls (autograd on: no fast path anywhere), detached."""
    with torch.enable_grad():
        out = LastLayerActor.encode_with_transition(actor, inputs[0], transition_model, *inputs[1:])
    return tuple(x.detach() for x in out)


def _fast(actor, transition_model, *inputs):
    with torch.no_grad():
        return actor.encode_with_transition(inputs[0], transition_model, *inputs[1:])


# ----------------------------------------------------------------------------- the mean action
def test_the_mean_equals_the_deterministic_one_step_planner_policy(make_model):
    model = make_model(num_steps=1)
    actor = PlannerActor(model)
    observation = torch.randn(6, 3) * 3.0 + 1.5
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        sampler_action, _ = PlannerSampler(model)(observation)
        policy_td = PlannerPolicy(model)(TensorDict({"observation": observation}, [6]))
    mu = actor(observation)
    assert mu.shape == (6, 2)
    torch.testing.assert_close(mu, sampler_action, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(mu, policy_td["action"], rtol=1e-5, atol=1e-5)


def test_the_mean_is_affine_in_the_head_weights(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(5, 3)
    gen = torch.Generator().manual_seed(3)
    w1, w2 = (torch.randn(actor.head.weight.shape, generator=gen) * 0.1 for _ in range(2))
    b1, b2 = (torch.randn(actor.head.bias.shape, generator=gen) * 0.1 for _ in range(2))
    with torch.no_grad():
        mu1 = _with_head(actor, w1, b1)(observation)
        mu2 = _with_head(actor, w2, b2)(observation)
        mu_mid = _with_head(actor, (w1 + w2) / 2, (b1 + b2) / 2)(observation)
        mu_ext = _with_head(actor, 2 * w1 - w2, 2 * b1 - b2)(observation)
    assert not torch.allclose(mu1, mu2)
    torch.testing.assert_close(mu_mid, (mu1 + mu2) / 2, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(mu_ext, 2 * mu1 - mu2, rtol=1e-5, atol=1e-5)


def test_readout_scale_is_the_derivative_of_the_action(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(4, 3)
    head = actor.head_output(actor.features(observation))
    delta = 0.5
    shifted = actor.readout(head + delta, observation) - actor.readout(head, observation)
    torch.testing.assert_close(shifted.abs() / delta, actor.readout_scale().expand(4, 2))
    torch.testing.assert_close(
        actor.readout_scale(), actor.sigma_1 * actor.model.normalizer.action_std
    )


def test_features_feed_the_head_that_gives_the_mean(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(4, 3)
    features = actor.features(observation)
    assert features.shape == (4, actor.head.in_features)
    assert actor.head is actor.model.denoiser.head
    assert actor.head_rows.tolist() == [3, 4]  # a_0: row 0, after the 3 state entries
    torch.testing.assert_close(
        actor.readout(actor.head_output(features), observation), actor(observation)
    )


# ----------------------------------------------------------------------------- fast path
@pytest.mark.parametrize("batch", [(), (7,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_fast_features_equal_the_plain_features(make_model, batch):
    actor = PlannerActor(make_model(num_steps=1))
    observation = transition_inputs(*batch)[0]
    with torch.no_grad():
        fast = actor.features(observation)
    with torch.enable_grad():
        plain = actor.features(observation)
    assert plain.requires_grad and not fast.requires_grad  # the two paths really ran
    torch.testing.assert_close(fast, plain.detach(), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
@pytest.mark.parametrize("kind", TRANSITIONS)
def test_encode_with_transition_fast_equals_the_generic_two_calls(
    make_model, monkeypatch, batch, kind
):
    actor = PlannerActor(make_model(num_steps=1))
    transition = _transition(actor, kind)
    inputs = transition_inputs(*batch)
    calls = []
    original = actor._fast.features_with_transition
    monkeypatch.setattr(
        actor._fast, "features_with_transition", lambda *a: calls.append(1) or original(*a)
    )
    fast = _fast(actor, transition, *inputs)
    assert calls == [1]  # the one-pass shortcut was taken
    features, context, predicted = fast
    assert features.shape == (*batch, actor.head.in_features)
    assert predicted.shape == inputs[0].shape
    torch.testing.assert_close(context, inputs[0])
    assert_all_close(fast, _generic(actor, transition, *inputs))
    torch.testing.assert_close(predicted, plain_prediction(transition.model, *inputs[1:]))


@pytest.mark.parametrize(
    "incompatible",
    ["multi-step", "sample-latent", "other-width"],
)
def test_an_incompatible_transition_model_falls_back_to_two_correct_calls(
    make_model, monkeypatch, incompatible
):
    actor = PlannerActor(make_model(num_steps=1))
    if incompatible == "multi-step":
        transition = TransitionModel(make_model(num_steps=2))
    elif incompatible == "sample-latent":
        transition = TransitionModel(fine_tuned(actor.model), latent="sample")
    else:
        other = TrajectoryDiffusion(actor.model.layout, num_steps=1, hidden=16, depth=1)
        other.normalizer.load_state_dict(actor.model.normalizer.state_dict())
        transition = TransitionModel(other)

    def not_taken(*args):
        raise AssertionError("the one-pass shortcut does not apply to this transition model")

    monkeypatch.setattr(actor._fast, "features_with_transition", not_taken)
    inputs = transition_inputs(4)
    torch.manual_seed(0)
    fast = _fast(actor, transition, *inputs)
    torch.manual_seed(0)
    with torch.no_grad():
        features = actor.features(inputs[0])
        predicted = transition.predict(*inputs[1:])
    assert_all_close(fast, (features, inputs[0], predicted))


def test_gradients_flow_through_the_policy_query_with_autograd(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    frozen = TransitionModel.frozen_copy(actor.model)
    observation, previous_observation, previous_action = transition_inputs(4)
    features, context, predicted = actor.encode_with_transition(
        observation, frozen, previous_observation, previous_action
    )
    assert features.requires_grad and not predicted.requires_grad
    actor.readout(actor.head_output(features), context).sum().backward()
    for name in ("input_layer.weight", "blocks.0.net.1.weight", "head.weight"):
        assert actor.model.denoiser.get_parameter(name).grad.abs().sum() > 0, name
    assert all(p.grad is None for p in frozen.parameters())
    shared = TransitionModel(actor.model, frozen=False)
    predicted = actor.encode_with_transition(
        observation, shared, previous_observation, previous_action
    )[2]
    assert predicted.requires_grad  # shared weights: ŝ_t is a function of the actor's θ


def test_a_mismatched_previous_observation_is_rejected(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    shared = TransitionModel(actor.model, frozen=False)
    with pytest.raises(ValueError, match=r"previous_observation \(4, 3\).*\(5, 3\)"):
        actor.encode_with_transition(
            torch.zeros(5, 3), shared, torch.zeros(4, 3), torch.zeros(4, 2)
        )


@pytest.mark.parametrize("change, kind", CHANGE_CASES)
def test_the_fast_path_follows_every_kind_of_weight_change(make_model, change, kind):
    actor = PlannerActor(make_model(num_steps=1))
    transition = _transition(actor, kind)
    inputs = transition_inputs(5)
    before = _fast(actor, transition, *inputs)  # fills every cache
    apply_weight_change(actor.model, change)
    if kind == "frozen-copy":
        apply_weight_change(transition.model, change)
    if change == "double":
        actor.double()
        inputs = tuple(x.double() for x in inputs)
    fast = _fast(actor, transition, *inputs)
    with torch.no_grad():
        folded = actor.features(inputs[0])
    if change != "double":
        assert not torch.allclose(fast[2], before[2], atol=1e-4)
    assert_all_close(fast, _generic(actor, transition, *inputs))
    torch.testing.assert_close(folded, fast[0], rtol=1e-5, atol=1e-5)


def test_the_paired_pass_follows_actor_training_and_leaves_a_frozen_copy_alone(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    frozen = TransitionModel.frozen_copy(actor.model)
    before = copy.deepcopy(frozen.state_dict())
    loss = WeightedMAPActorLoss(actor, weighting="uniform")
    optimizer = torch.optim.Adam(loss.parameters(), lr=0.05)
    inputs = transition_inputs(8)
    first = _fast(actor, frozen, *inputs)  # fills the caches
    batch = TensorDict(observation=inputs[0], action=torch.randn(8, 2), batch_size=[8])
    for _ in range(3):
        optimizer.zero_grad()
        loss(batch)["loss_actor"].backward()
        assert all(p.grad is None for p in frozen.parameters())
        optimizer.step()
    for key, value in frozen.state_dict().items():
        assert torch.equal(value, before[key]), key
    after = _fast(actor, frozen, *inputs)
    assert not torch.allclose(after[0], first[0], atol=1e-4)  # the actor moved
    torch.testing.assert_close(after[2], first[2])  # ŝ_t did not
    assert_all_close(after, _generic(actor, frozen, *inputs))


# ----------------------------------------------------------------------------- options
def test_bad_options_are_rejected(make_model):
    with pytest.raises(ValueError, match="choose one of"):
        PlannerActor(make_model(num_steps=1), latent="mean")
    with pytest.raises(ValueError, match="init_std"):
        PlannerActor(make_model(num_steps=1), init_std=5.0)
    with pytest.raises(ValueError, match="observation must end with dim 3"):
        PlannerActor(make_model(num_steps=1))(torch.randn(2, 4))


def test_a_sampled_latent_needs_a_schedule_that_ends_in_pure_noise(make_model, make_layout):
    from torchrl_dual.diffusion import TrajectoryDiffusion

    linear = TrajectoryDiffusion(make_layout(), schedule="linear", num_steps=1, hidden=8, depth=1)
    with pytest.raises(ValueError, match=r"latent='sample' needs .*'linear' schedule has α_1"):
        PlannerActor(linear, latent="sample")
    PlannerActor(linear)  # the zero latent is fine with any schedule


def test_a_sampled_latent_draws_a_new_mean_at_every_call(make_model):
    actor = PlannerActor(make_model(num_steps=1), latent="sample")
    observation = torch.randn(4, 3)
    with torch.no_grad():
        assert not torch.allclose(actor(observation), actor(observation))
    zero = PlannerActor(actor.model)
    with torch.no_grad():
        assert torch.equal(zero(observation), zero(observation))


def test_a_deep_copy_of_the_actor_takes_the_fast_path_with_its_own_weights(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    inputs = transition_inputs(4)
    shared = TransitionModel(actor.model, frozen=False)
    before = _fast(actor, shared, *inputs)  # caches filled before the copy
    twin = copy.deepcopy(actor)
    twin_shared = TransitionModel(twin.model, frozen=False)
    with torch.no_grad():
        twin.model.denoiser.input_layer.weight.mul_(-1.0)
    fast = _fast(twin, twin_shared, *inputs)
    assert not torch.allclose(fast[0], before[0])
    assert_all_close(fast, _generic(twin, twin_shared, *inputs))
    assert_all_close(_fast(actor, shared, *inputs), before)  # the original is untouched


# ----------------------------------------------------------------------------- N steps ("w/o distillation")
def _fitted(model: TrajectoryDiffusion) -> TrajectoryDiffusion:
    """Non-trivial normalizer statistics, so that a wrong offset or scale shows."""
    model.normalizer.fit(torch.randn(256, 3) * 2.0 + 1.0, torch.randn(256, 2) * 0.5 + 0.3)
    return model


def test_an_n_step_mean_is_the_deterministic_n_step_planner_a0(make_model):
    torch.manual_seed(0)
    model = _fitted(make_model(num_steps=8))
    actor = PlannerActor(model)
    observation = torch.randn(6, 3) * 2.0
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        sampler_action, _ = PlannerSampler(model)(observation)
        policy_action = PlannerPolicy(model)(TensorDict({"observation": observation}, [6]))[
            "action"
        ]
    # an independent DDIM run: 8 ddim_step calls, a_0 read out and denormalised
    layout, norm = model.layout, model.normalizer
    cond, mask = layout.conditioned_window(norm.normalize_observation(observation))
    z, times = cond, torch.linspace(1.0, 0.0, 9)
    for t, s in zip(times[:-1], times[1:], strict=True):
        z = model.ddim_step(z, t.expand(6), s.expand(6), cond, mask.expand_as(cond))
    reference = norm.denormalize_action(z[:, 0, 3:])
    with torch.no_grad():
        mean = actor(observation)
    for other in (sampler_action, policy_action, reference):
        torch.testing.assert_close(mean, other.detach(), rtol=1e-5, atol=1e-5)
    assert actor._fast is None  # N > 1: the plain path


def test_an_n_step_action_is_affine_in_the_last_step_head(make_model):
    """Eq. 8 stays exact: a perturbed head changes μ by readout_scale ⊙ (ΔW φ + Δb), with
    φ and the offset from the chain at the MAP weights."""
    torch.manual_seed(1)
    actor = PlannerActor(_fitted(make_model(num_steps=8)))
    observation = torch.randn(5, 3)
    with torch.no_grad():
        features, context = actor.encode(observation)
        mean = actor.readout(actor.head_output(features), context)
        torch.testing.assert_close(mean, actor(observation))
        rows = actor.head_rows
        d_weight = 0.1 * torch.randn(2, actor.head.in_features)
        d_bias = 0.1 * torch.randn(2)
        # the last step alone, with the head perturbed: the chain before it keeps θ*
        moved = actor.readout(
            torch.nn.functional.linear(
                features, actor.head.weight[rows] + d_weight, actor.head.bias[rows] + d_bias
            ),
            context,
        )
        linear = mean - actor.readout_scale() * (features @ d_weight.T + d_bias)
    torch.testing.assert_close(moved, linear, rtol=1e-5, atol=1e-5)
    # readout_scale is |∂μ / ∂ head|: σ_{1/N} · action_std
    _, sigma = actor.model.schedule(torch.tensor(1.0 / 8))
    torch.testing.assert_close(
        actor.readout_scale(), float(sigma) * actor.model.normalizer.action_std
    )


def test_an_n_step_actor_trains_through_the_whole_chain(make_model):
    actor = PlannerActor(make_model(num_steps=4))
    actor(torch.randn(8, 3)).pow(2).sum().backward()
    grads = {name: p.grad for name, p in actor.model.denoiser.named_parameters()}
    assert all(g is not None and g.abs().sum() > 0 for g in grads.values())


def test_sampled_latents_give_distinct_members_whose_zero_latent_is_the_mean(
    make_model, monkeypatch
):
    torch.manual_seed(2)
    actor = PlannerActor(_fitted(make_model(num_steps=4)))
    observation = torch.randn(3, 3)
    with torch.no_grad():
        members = actor.sample_actions(observation, 6)
        assert members.shape == (6, 3, 2)
        assert (members.std(0) > 1e-4).all()  # the latent changes the action
        # the chain with z_1 = 0 through sample_actions' path is the actor's mean
        monkeypatch.setattr(torch, "randn_like", lambda x, **_: torch.zeros_like(x))
        zero = actor.sample_actions(observation, 2)
        torch.testing.assert_close(zero[0], actor(observation), rtol=1e-5, atol=1e-5)


def test_laplace_members_of_an_n_step_actor_sample_the_last_step_head_only(make_model):
    """Each member of Eq. 9 is the chain at θ* for N − 1 steps, then the last step with
    the member's head: an independent run with a copied model gives the same actions."""
    torch.manual_seed(3)
    model = _fitted(make_model(num_steps=4))
    actor = PlannerActor(model)
    ensemble = LaplaceEnsembleActor(actor, num_samples=3)
    ensemble.fit_laplace([TensorDict(observation=torch.randn(128, 3), batch_size=[128])])
    assert ensemble.weight_deviation.abs().sum() > 0
    observation = torch.randn(5, 3)
    with torch.no_grad():
        members = ensemble.member_actions(observation)
        layout, norm = model.layout, model.normalizer
        cond, mask = layout.conditioned_window(norm.normalize_observation(observation))
        mask = mask.expand_as(cond)
        z, times = cond, torch.linspace(1.0, 0.0, 5)
        for t, s in zip(times[:-2], times[1:-1], strict=True):
            z = model.ddim_step(z, t.expand(5), s.expand(5), cond, mask)
        for m in range(3):
            member = copy.deepcopy(model)
            member.denoiser.head.weight[actor.head_rows] += ensemble.weight_deviation[m]
            member.denoiser.head.bias[actor.head_rows] += ensemble.bias_deviation[m]
            x_hat = member.predict(z, times[-2].expand(5), cond, mask)[0]
            expected = norm.denormalize_action(x_hat[:, 0, 3:])
            torch.testing.assert_close(members[m], expected, rtol=1e-5, atol=1e-5)
    assert (members.std(0) > 0).all()


def test_a_sampled_latent_schedule_error_names_the_fix(make_layout):
    linear = TrajectoryDiffusion(make_layout(), schedule="linear", num_steps=1, hidden=8, depth=1)
    with pytest.raises(ValueError, match=r"; use the cosine schedule or latent='zero'\.$"):
        PlannerActor(linear, latent="sample")


def test_an_n_step_actor_with_a_sampled_latent_draws_the_chain_from_noise(make_model):
    """N > 1 with ``latent="sample"``: the mean is the chain from a drawn ``z_1`` (the draw
    ``sample_actions`` makes for one member), a new one at every call."""
    actor = PlannerActor(make_model(num_steps=4), latent="sample")
    observation = torch.randn(5, 3)
    with torch.no_grad():
        torch.manual_seed(3)
        first = actor(observation)
        second = actor(observation)
        torch.manual_seed(3)
        member = actor.sample_actions(observation, 1)[0]
        zero = PlannerActor(actor.model)(observation)
    torch.testing.assert_close(first, member)
    assert not torch.allclose(first, second)
    assert not torch.allclose(first, zero)


def test_the_previous_action_is_cast_to_the_observation_dtype(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    shared = TransitionModel(actor.model, frozen=False)
    observation, previous_observation, previous_action = transition_inputs(4)
    expected = _fast(actor, shared, observation, previous_observation, previous_action)
    fast = _fast(actor, shared, observation, previous_observation, previous_action.double())
    assert fast[2].dtype == torch.float32
    assert_all_close(fast, expected)
