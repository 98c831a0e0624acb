"""Tests for the Laplace ensemble policy of DUAL (Eq. 8 fit, Eq. 9 policy, Eq. 10 in a collector)."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ValueOperator
from toy import assert_all_close, fine_tuned, previous_step_td

from torchrl_dual.diffusion import TrajectoryLayout
from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    LinearHeadActor,
    PlannerActor,
    ShiftAwareNoise,
    TransitionModel,
)
from torchrl_dual.modules.actors.last_layer_actor import TanhSquash
from torchrl_dual.objectives.weighted_map_actor import WeightedMAPActorLoss
from torchrl_dual.transforms import PreviousTransition

OBS, ACT = 2, 2
ACTOR_KINDS = ("linear_head", "planner")


# ----------------------------------------------------------------------------- factories
def _training_data(
    n: int = 256, obs_dim: int = OBS, action_dim: int = ACT, seed: int = 0
) -> TensorDict:
    """States in a small cluster around the origin; actions a smooth function of the state."""
    gen = torch.Generator().manual_seed(seed)
    observation = torch.randn(n, obs_dim, generator=gen) * 0.3
    action = torch.tanh(observation[:, :action_dim]) + 0.1 * torch.randn(
        n, action_dim, generator=gen
    )
    return TensorDict({"observation": observation, "action": action}, [n])


def _actor(kind: str, make_model, data: TensorDict | None = None, seed: int = 0):
    """A tiny ``LinearHeadActor`` (ReLU ``MLP``) or ``PlannerActor`` (normalizer fitted on ``data``)."""
    data = _training_data() if data is None else data
    if kind == "linear_head":
        torch.manual_seed(seed)
        net = MLP(in_features=OBS, out_features=ACT, num_cells=[16, 16], activation_class=nn.ReLU)
        return LinearHeadActor(net, ACT)
    model = make_model(TrajectoryLayout(OBS, ACT, 4), num_steps=1, fit=False, seed=seed)
    model.normalizer.fit(data["observation"], data["action"] * 2.0)  # readout_scale != 1
    return PlannerActor(model)


def _fitted_policy(kind: str, make_model, num_samples: int = 8, **kwargs) -> LaplaceEnsembleActor:
    data = _training_data()
    policy = LaplaceEnsembleActor(_actor(kind, make_model, data), num_samples=num_samples, **kwargs)
    policy.fit_laplace([data[:128], data[128:]])
    return policy


def _obs_td(batch: int = 5, seed: int = 1, scale: float = 0.5) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict({"observation": torch.randn(batch, OBS, generator=gen) * scale}, [batch])


# ----------------------------------------------------------------------------- (a) one pass
@pytest.mark.parametrize("num_samples", [1, 64])
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_trunk_and_head_run_once_per_forward_for_any_ensemble_size(
    kind, num_samples, make_model, monkeypatch
):
    policy = _fitted_policy(kind, make_model, num_samples=num_samples)
    calls = {"features": 0, "head_output": 0, "weight_samples_split": 0}

    def counted(obj, name):
        original = getattr(obj, name)

        def wrapper(*args, **kwargs):
            calls[name] += 1
            return original(*args, **kwargs)

        monkeypatch.setattr(obj, name, wrapper)

    counted(policy.actor, "features")
    counted(policy.actor, "head_output")
    counted(policy.laplace, "weight_samples_split")
    out = policy(_obs_td(7))
    # One trunk pass; the MAP head and the M deviations form one batched contraction
    # (no separate head pass); the M sub-policies are drawn at fit time, not here.
    assert calls == {"features": 1, "head_output": 0, "weight_samples_split": 0}
    assert policy.member_actions(_obs_td(7)["observation"]).shape == (num_samples, 7, ACT)
    assert out["action"].shape == out["loc"].shape == out["epistemic_variance"].shape == (7, ACT)
    assert out["action_log_prob"].shape == (7,)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        policy(_obs_td(7))
    assert calls["features"] == 3  # member_actions above + the deterministic pass


# ----------------------------------------------------------------------------- (b) members
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_member_actions_equal_explicit_per_member_heads(kind, make_model):
    policy = _fitted_policy(kind, make_model, num_samples=6)
    observation = _obs_td(5)["observation"]
    torch.manual_seed(123)
    policy.resample()
    members = policy.member_actions(observation)
    torch.manual_seed(123)
    weight, bias = policy.laplace.weight_samples_split(6)
    rows = policy.actor.head_rows
    for m in range(6):
        member = copy.deepcopy(policy.actor)
        with torch.no_grad():
            member.head.weight[rows] = weight[m]
            member.head.bias[rows] = bias[m]
            expected = member(observation)
        torch.testing.assert_close(members[m], expected, rtol=1e-4, atol=1e-5)
    assert members.std(0).min() > 0  # members really differ


@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_inference_members_follow_resampling_and_optimizer_steps(kind, make_model):
    """Without autograd the stacked member heads are cached; every change must show."""
    policy = _fitted_policy(kind, make_model, num_samples=4)
    observation = _obs_td(5)["observation"]

    def both():
        with torch.no_grad():
            cached = policy.member_actions(observation)
        with torch.enable_grad():
            fresh = policy.member_actions(observation).detach()
        torch.testing.assert_close(cached, fresh, rtol=1e-5, atol=1e-6)
        return cached

    first = both()
    policy.resample()
    second = both()
    assert not torch.allclose(first, second)
    optimizer = torch.optim.SGD(policy.actor.parameters(), lr=0.5)
    (policy.actor(observation) ** 2).sum().backward()
    optimizer.step()
    assert not torch.allclose(both(), second)


@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_members_are_centred_on_the_current_head_between_refits(kind, make_model):
    policy = _fitted_policy(kind, make_model, num_samples=6)
    observation = _obs_td(5)["observation"]
    with torch.no_grad():
        policy.actor.head.bias.add_(0.3)  # the actor trains on after the fit
    torch.manual_seed(0)
    policy.resample()
    members = policy.member_actions(observation)
    torch.manual_seed(0)
    weight, bias = policy.laplace.weight_samples_split(6)
    theta = policy.laplace.theta_map.float()
    deviation = torch.einsum(
        "bd,mad->mba", policy.actor.features(observation), weight - theta[:, :-1]
    )
    head = policy.actor.head_output(policy.actor.features(observation))
    expected = policy.actor.readout(head + deviation + (bias - theta[:, -1])[:, None], observation)
    torch.testing.assert_close(members, expected, rtol=1e-4, atol=1e-5)


# ----------------------------------------------------------------------------- (c) Eq. 9
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_loc_scale_and_epistemic_follow_eq_9(kind, make_model):
    policy = _fitted_policy(kind, make_model, num_samples=7)
    td = _obs_td(6)
    torch.manual_seed(7)
    out = policy(td.clone())
    torch.manual_seed(7)
    members = policy.member_actions(td["observation"])
    eps = torch.randn(6, ACT)
    loc = members.sum(0) / 7
    epistemic = ((members - loc) ** 2).sum(0) / 7  # population variance
    aleatoric = policy.actor.std.detach() ** 2
    torch.testing.assert_close(out["loc"], loc)
    torch.testing.assert_close(out["epistemic_variance"], epistemic)
    torch.testing.assert_close(out["scale"] ** 2, epistemic + aleatoric)
    torch.testing.assert_close(out["action"], loc + out["scale"] * eps)
    log_prob = torch.distributions.Normal(loc, out["scale"]).log_prob(out["action"]).sum(-1)
    torch.testing.assert_close(out["action_log_prob"], log_prob)


def test_sampled_action_is_clamped_to_the_bounds(make_model):
    policy = _fitted_policy("linear_head", make_model, action_low=-0.01, action_high=0.01)
    out = policy(_obs_td(64, scale=3.0))
    assert out["action"].abs().max() <= 0.01
    assert out["loc"].abs().max() > 0.01  # loc is not clamped


# ----------------------------------------------------------------------------- (d) modes
@pytest.mark.parametrize(
    "mode", [ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN]
)
def test_deterministic_modes_return_the_map_mean_without_sampling(mode, make_model):
    policy = _fitted_policy("planner", make_model)
    td = _obs_td(5)
    with set_exploration_type(mode):
        first, second = policy(td.clone()), policy(td.clone())
    mu = policy.actor(td["observation"])
    for out in (first, second):
        torch.testing.assert_close(out["loc"], mu)
        torch.testing.assert_close(out["action"], mu)
        assert torch.equal(out["epistemic_variance"], torch.zeros(5, ACT))
        torch.testing.assert_close(out["scale"], policy.actor.std.detach().expand(5, ACT))
    assert torch.equal(first["action"], second["action"])


def test_random_mode_calls_differ(make_model):
    policy = _fitted_policy("planner", make_model)
    td = _obs_td(5)
    with set_exploration_type(ExplorationType.RANDOM):
        first, second = policy(td.clone()), policy(td.clone())
    assert not torch.allclose(first["action"], second["action"])
    # The M sub-policies are maintained between refits: same ensemble, same μ(s).
    torch.testing.assert_close(first["loc"], second["loc"])
    assert (first["epistemic_variance"] > 0).all()


def test_resample_each_call_draws_new_sub_policies_at_every_step(make_model):
    policy = _fitted_policy("planner", make_model)
    policy.resample_each_call = True
    td = _obs_td(5)
    with set_exploration_type(ExplorationType.RANDOM):
        first, second = policy(td.clone()), policy(td.clone())
    assert not torch.allclose(first["loc"], second["loc"])


def test_resample_draws_a_new_ensemble_and_refit_redraws(make_model):
    policy = _fitted_policy("linear_head", make_model)
    before = policy.weight_deviation.clone()
    policy.resample()
    assert not torch.equal(before, policy.weight_deviation)
    assert "weight_deviation" in policy.state_dict()


# ----------------------------------------------------------------------------- (e) distance
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_epistemic_variance_grows_with_distance_from_the_training_states(kind, make_model):
    policy = _fitted_policy(kind, make_model, num_samples=2048)
    gen = torch.Generator().manual_seed(5)
    directions = torch.nn.functional.normalize(torch.randn(16, OBS, generator=gen), dim=-1)
    closed_form, monte_carlo = [], []
    for radius in (0.0, 1.0, 2.0, 4.0, 8.0):
        observation = directions * radius
        with torch.no_grad():
            features = policy.actor.features(observation)
            variance = (
                policy.laplace.predictive_variance(features) * policy.actor.readout_scale() ** 2
            )
            out = policy(TensorDict({"observation": observation}, [16]))
        closed_form.append(float(variance.mean()))
        monte_carlo.append(float(out["epistemic_variance"].mean()))
    assert all(a < b for a, b in zip(closed_form[:-1], closed_form[1:], strict=True)), closed_form
    assert all(a < b for a, b in zip(monte_carlo[:-1], monte_carlo[1:], strict=True)), monte_carlo
    assert closed_form[-1] > 50 * closed_form[0]
    for cf, mc in zip(closed_form, monte_carlo, strict=True):
        assert mc == pytest.approx(cf, rel=0.15)


# ----------------------------------------------------------------------------- (f) fit
def _advantage_loss(actor) -> WeightedMAPActorLoss:
    torch.manual_seed(0)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    value = ValueOperator(
        MLP(in_features=OBS, out_features=1, num_cells=[8]), in_keys=["observation"]
    )
    return WeightedMAPActorLoss(actor, qvalue_network=qvalue, value_network=value, temperature=3.0)


def test_fit_with_advantage_weights_accumulates_the_weighted_gram_matrix(make_model):
    data = _training_data()
    actor = _actor("planner", make_model, data)
    policy = LaplaceEnsembleActor(actor, num_samples=8)
    loss_fn = _advantage_loss(actor)
    laplace = policy.fit_laplace([data[:100], data[100:]], weight_fn=loss_fn.advantage_weights)

    weights = loss_fn.advantage_weights(data).double()
    assert weights.std() > 0.1  # the weights are not uniform
    with torch.no_grad():
        phi = actor.features(data["observation"]).double()
    phi = torch.cat([phi, torch.ones(len(phi), 1, dtype=phi.dtype)], -1)
    torch.testing.assert_close(laplace.G_raw, (phi * weights[:, None]).T @ phi)
    torch.testing.assert_close(laplace.sum_weights, weights.sum())
    assert bool(laplace.fitted)
    sigma_head = actor.std.detach().double() / actor.readout_scale().double()
    torch.testing.assert_close(laplace.noise_variance, sigma_head**2)
    rows = actor.head_rows
    torch.testing.assert_close(laplace.theta_map[:, :-1].float(), actor.head.weight[rows].detach())

    uniform = LaplaceEnsembleActor(copy.deepcopy(actor)).fit_laplace([data])
    assert not torch.allclose(
        uniform.predictive_variance(phi[:, :-1]), laplace.predictive_variance(phi[:, :-1])
    )


def test_refit_after_the_head_changes_recentres_the_ensemble(make_model):
    policy = _fitted_policy("linear_head", make_model, num_samples=4096)
    observation = _obs_td(5)["observation"]
    old_theta = policy.laplace.theta_map.clone()
    with torch.no_grad():
        policy.actor.head.weight.mul_(1.5)
        policy.actor.head.bias.add_(0.5)
    policy.fit_laplace([_training_data()])
    new_theta = policy.laplace.theta_map
    assert not torch.allclose(new_theta, old_theta)
    head = policy.actor.head
    torch.testing.assert_close(
        new_theta.float(), torch.cat([head.weight, head.bias[:, None]], 1).detach()
    )
    # The posterior samples are centred on the new MAP head: their mean is the new μ(s).
    weight, bias = policy.laplace.weight_samples_split(4096)
    torch.testing.assert_close(weight.mean(0), head.weight.detach(), atol=0.05, rtol=0)
    torch.testing.assert_close(bias.mean(0), head.bias.detach(), atol=0.05, rtol=0)
    with torch.no_grad():
        out = policy(TensorDict({"observation": observation}, [5]))
        mu = policy.actor(observation)
    spread = out["epistemic_variance"].sqrt()
    assert ((out["loc"] - mu).abs() < 4 * spread / 64 + 1e-4).all()


# ----------------------------------------------------------------------------- (g) actors
def test_wraps_a_torchrl_mlp_actor_as_iql_plus_la_and_a_planner_actor(make_model):
    for kind in ACTOR_KINDS:
        policy = _fitted_policy(kind, make_model)
        out = policy(_obs_td(3))
        assert set(policy.out_keys) <= set(out.keys())
        assert out["scale"].shape == (3, ACT)
        assert policy.laplace.in_features == policy.actor.head.in_features
    mlp = MLP(in_features=OBS, out_features=2 * ACT, num_cells=[8])  # loc and scale halves
    policy = LaplaceEnsembleActor(LinearHeadActor(mlp, ACT), num_samples=4)
    assert policy.laplace.out_features == ACT
    policy.fit_laplace([_training_data()])
    assert policy(_obs_td(3))["action"].shape == (3, ACT)


# ----------------------------------------------------------------------------- (h) collector
@pytest.mark.parametrize("kind", ["shared", "frozen-copy"])
def test_collects_pendulum_with_shift_aware_noise_and_stores_all_keys(make_model, kind):
    from torchrl.collectors import Collector
    from torchrl.envs import GymEnv, TransformedEnv

    env = TransformedEnv(GymEnv("Pendulum-v1"))
    env.append_transform(PreviousTransition())
    env.set_seed(0)
    torch.manual_seed(0)
    model = make_model(TrajectoryLayout(3, 1, 4), num_steps=1, fit=False)
    observation = env.observation_spec["observation"].rand((256,))
    model.normalizer.fit(observation, env.action_spec.rand((256,)))
    transition = (
        TransitionModel(model, frozen=False)
        if kind == "shared"
        else TransitionModel(fine_tuned(model, scale=0.1))
    )
    ensemble = LaplaceEnsembleActor(
        PlannerActor(model), num_samples=5, sample_action=False, transition_model=transition
    )
    ensemble.fit_laplace([TensorDict({"observation": observation}, [256])])
    policy = TensorDictSequential(ensemble, ShiftAwareNoise(env.action_spec))
    collector = Collector(
        env, policy, frames_per_batch=50, total_frames=100, auto_register_policy_transforms=False
    )
    try:
        batches = list(collector)
    finally:
        collector.shutdown()
    assert len(batches) == 2
    for data in batches:
        assert data.batch_size == (50,)
        for key in ("action", "loc", "scale", "epistemic_variance", "shift_distance"):
            assert key in data.keys(True, True), key
        assert (data["epistemic_variance"] > 0).all()
        assert data["action"].abs().max() <= 2.0  # projected on the Pendulum action spec
        std = policy[0].actor.std.detach()
        torch.testing.assert_close(data["scale"] ** 2, data["epistemic_variance"] + std**2)
        # d_t = ‖p(s' | s_(t-1), a_(t-1)) − s_t‖ with the executed a_(t-1); 0 after reset
        valid = data["previous_valid"]
        with torch.no_grad():
            predicted = transition.predict(data["previous_observation"], data["previous_action"])
        expected = torch.where(
            valid, (predicted - data["observation"]).norm(dim=-1, keepdim=True), 0
        )
        torch.testing.assert_close(data["shift_distance"], expected, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(
            data["previous_action"][1:][valid[1:, 0]], data["action"][:-1][valid[1:, 0]]
        )
        assert (data["shift_distance"][valid] > 0).all()
        scale = (data["scale"] ** 2 + 0.5 * data["shift_distance"]).sqrt()
        torch.testing.assert_close(data["exploration_scale"], scale)


# ----------------------------------------------------------------------------- (i) errors
def test_random_mode_before_fit_raises_and_deterministic_mode_works(make_model):
    policy = LaplaceEnsembleActor(_actor("linear_head", make_model))
    with pytest.raises(RuntimeError, match="call fit_laplace"):
        policy(_obs_td())
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert policy(_obs_td())["action"].shape == (5, ACT)


def test_missing_observation_key_and_bad_ensemble_size_are_rejected(make_model):
    policy = _fitted_policy("linear_head", make_model)
    with pytest.raises(KeyError, match="reads 'observation'.*holds \\['obs'\\]"):
        policy(TensorDict({"obs": torch.zeros(3, OBS)}, [3]))
    with pytest.raises(ValueError, match="num_samples"):
        LaplaceEnsembleActor(_actor("linear_head", make_model), num_samples=-1)


def test_custom_observation_and_output_keys(make_model):
    data = _training_data()
    policy = LaplaceEnsembleActor(
        _actor("linear_head", make_model, data),
        observation_key=("agent", "obs"),
        loc_key="mu",
        epistemic_key="var_e",
    )
    policy.fit_laplace([TensorDict({("agent", "obs"): data["observation"]}, [256])])
    out = policy(TensorDict({("agent", "obs"): torch.zeros(3, OBS)}, [3]))
    assert {"mu", "var_e", "scale", "action"} <= set(out.keys())


# ----------------------------------------------------------------------------- (j) state_dict
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_state_dict_round_trip_gives_identical_outputs_with_the_same_seed(kind, make_model):
    policy = _fitted_policy(kind, make_model)
    state = policy.state_dict()
    for name in ("G_raw", "theta_map", "prior_precision", "eigenvectors", "sample_scale", "fitted"):
        assert f"laplace.{name}" in state
    restored = LaplaceEnsembleActor(_actor(kind, make_model, seed=1), num_samples=8)
    assert not bool(restored.laplace.fitted)
    restored.load_state_dict(state)
    td = _obs_td(4)
    outputs = []
    for module in (policy, restored):
        torch.manual_seed(11)
        outputs.append(module(td.clone()))
    for key in ("action", "loc", "scale", "epistemic_variance", "action_log_prob"):
        assert torch.equal(outputs[0][key], outputs[1][key]), key


def test_fit_laplace_names_a_missing_observation_key(make_model):
    policy = LaplaceEnsembleActor(_actor("linear_head", make_model))
    with pytest.raises(KeyError, match="observation"):
        policy.fit_laplace([TensorDict({"obs": torch.zeros(3, OBS)}, [3])])


def test_without_sample_action_the_ensemble_leaves_the_draw_to_the_next_module(make_model):
    policy = _fitted_policy("linear_head", make_model)
    policy.sample_action = False
    with set_exploration_type(ExplorationType.RANDOM):
        out = policy(_obs_td(5))
    torch.testing.assert_close(out["action"], out["loc"])
    assert "action_log_prob" not in out.keys()
    assert (out["epistemic_variance"] > 0).all()


# ----------------------------------------------------------------------------- (k) transition
def _previous_td(batch: int = 6, valid=None) -> TensorDict:
    return previous_step_td(batch, valid=valid, obs_dim=OBS, action_dim=ACT, observation_scale=0.2)


@pytest.mark.parametrize("kind", ["shared", "frozen-copy", "linear-head"])
def test_with_a_transition_model_the_ensemble_also_writes_the_expected_observation(
    make_model, kind
):
    if kind == "linear-head":  # any last-layer actor: the generic two calls
        policy = _fitted_policy("linear_head", make_model)
        transition = TransitionModel(_actor("planner", make_model).model)
    else:
        policy = _fitted_policy("planner", make_model)
        model = policy.actor.model
        transition = (
            TransitionModel(model, frozen=False)
            if kind == "shared"
            else TransitionModel.frozen_copy(fine_tuned(model))
        )
    policy.transition_model = transition
    valid = torch.tensor([[True], [False], [True], [True], [False], [True]])
    td = _previous_td(valid=valid)
    torch.manual_seed(2)
    with torch.no_grad():  # the action path: one-pass shortcut for the planner actor
        with_transition = policy(td.clone())
    torch.manual_seed(2)
    policy.transition_model = None
    without = policy(td.clone())  # autograd on: the plain trunk pass
    predicted = transition.predict(td["previous_observation"], td["previous_action"])
    expected = torch.where(valid, predicted, td["observation"])
    torch.testing.assert_close(with_transition["expected_observation"], expected)
    assert "expected_observation" not in without.keys()
    keys = ("loc", "scale", "epistemic_variance", "action", "action_log_prob")
    assert_all_close([with_transition[k] for k in keys], [without[k] for k in keys])


def test_the_transition_model_adds_its_keys_and_is_registered_once(make_model):
    actor = _actor("planner", make_model)
    frozen = TransitionModel.frozen_copy(actor.model)
    policy = LaplaceEnsembleActor(actor, transition_model=frozen)
    assert policy.in_keys == [
        "observation",
        "previous_observation",
        "previous_action",
        "previous_valid",
    ]
    assert policy.out_keys[-1] == "expected_observation"
    state = policy.state_dict()
    frozen_keys = [key for key in state if key.startswith("transition_model.")]
    assert sorted(frozen_keys) == sorted(
        f"transition_model.model.{k}" for k in frozen.model.state_dict()
    )
    shared = LaplaceEnsembleActor(
        actor, transition_model=TransitionModel(actor.model, frozen=False)
    )
    assert not any(key.startswith("transition_model.") for key in shared.state_dict())
    assert set(shared.state_dict()) == set(LaplaceEnsembleActor(actor).state_dict())


def test_deterministic_modes_skip_the_transition_query(make_model):
    policy = _fitted_policy("planner", make_model)
    policy.transition_model = TransitionModel(policy.actor.model, frozen=False)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = policy(_obs_td(4))  # no previous_* entries needed
    assert "expected_observation" not in out.keys()
    torch.testing.assert_close(out["action"], policy.actor(_obs_td(4)["observation"]))


def test_a_missing_previous_entry_names_the_ensemble_and_the_transform(make_model):
    policy = _fitted_policy("planner", make_model)
    policy.transition_model = TransitionModel(policy.actor.model, frozen=False)
    with pytest.raises(
        KeyError, match=r"LaplaceEnsembleActor reads 'previous_action'.*PreviousTransition"
    ):
        policy(_previous_td().exclude("previous_action"))


def test_a_non_last_layer_actor_or_transition_model_is_rejected(make_model):
    with pytest.raises(TypeError, match=r"needs a LastLayerActor.*got Linear.*from_actor"):
        LaplaceEnsembleActor(nn.Linear(2, 2))
    actor = _actor("planner", make_model)
    with pytest.raises(TypeError, match="transition_model must be a TransitionModel, got function"):
        LaplaceEnsembleActor(actor, transition_model=lambda s, a: s)


def test_a_frozen_transition_model_on_the_actors_own_planner_is_refused(make_model):
    from torchrl_dual.modules import PlannerActor, TransitionModel

    model = make_model(num_steps=1)
    actor = PlannerActor(model)
    with pytest.raises(ValueError, match="frozen=False"):
        LaplaceEnsembleActor(actor, transition_model=TransitionModel(model))


# ----------------------------------------------------------------------------- no-UQ ablation
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_zero_samples_act_with_the_map_mean_and_the_aleatoric_std_only(kind, make_model):
    actor = _actor(kind, make_model)
    policy = LaplaceEnsembleActor(actor, num_samples=0, sample_action=False)  # no fit needed
    td = _obs_td()
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        out = policy(td.clone())
        mean = actor(td["observation"])
    assert_all_close(out["loc"], mean)
    assert_all_close(out["scale"], actor.std.expand_as(mean))
    assert not out["epistemic_variance"].any()
    sampled = LaplaceEnsembleActor(actor, num_samples=0)
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        first, second = sampled(td.clone())["action"], sampled(td.clone())["action"]
    assert not torch.equal(first, second)  # still explores with σ̄
    with pytest.raises(ValueError, match="num_samples"):
        LaplaceEnsembleActor(actor, num_samples=-1)


# ----------------------------------------------------------------------------- squashed actor
def _squashed_pair(num_samples: int = 6):
    """The same fitted ensemble twice: with ``TanhSquash(low, high)`` and without (shared
    weights, posterior and draws); ``(squashed, affine, low, high)``."""
    low, high = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0])
    affine = _fitted_policy("linear_head", None, num_samples=num_samples)
    layers = nn.Sequential(*affine.actor.trunk, affine.actor.head)  # the same weights
    squashed_actor = LinearHeadActor(layers, ACT, squash=TanhSquash(low, high))
    squashed = LaplaceEnsembleActor(squashed_actor, num_samples=num_samples)
    squashed.load_state_dict(affine.state_dict(), strict=False)  # σ̄, posterior, draws
    return squashed, affine, low, high


def test_squashed_members_are_the_squash_of_the_affine_members():
    squashed, affine, low, high = _squashed_pair()
    assert affine.actor.squash is None and squashed.actor.head is affine.actor.head
    observation = _obs_td(9, scale=3.0)["observation"]
    with torch.no_grad():
        pre = affine.member_actions(observation)
        members = squashed.member_actions(observation)
    torch.testing.assert_close(members, low + (high - low) * (torch.tanh(pre) + 1) / 2)
    assert (members >= low).all() and (members <= high).all()


def test_squashed_loc_and_epistemic_are_the_mean_and_variance_of_the_squashed_members():
    squashed, affine, low, high = _squashed_pair(num_samples=7)
    td = _obs_td(6, scale=3.0)
    with torch.no_grad():
        out = squashed(td.clone())
        members = squashed.member_actions(td["observation"])
        pre_loc = affine(td.clone())["loc"]
    torch.testing.assert_close(out["loc"], members.mean(0))
    torch.testing.assert_close(out["epistemic_variance"], members.var(0, correction=0))
    torch.testing.assert_close(out["scale"] ** 2, out["epistemic_variance"] + squashed.actor.std**2)
    assert (out["epistemic_variance"] > 0).all()
    # Eq. 9 averages actions: the mean of tanh is not tanh of the mean
    assert not torch.allclose(out["loc"], low + (high - low) * (torch.tanh(pre_loc) + 1) / 2)


def test_a_squashed_actor_has_the_same_posterior_and_a_squashed_map_action():
    squashed, affine, low, high = _squashed_pair()
    data = _training_data()
    squashed.fit_laplace([data])
    affine.fit_laplace([data])
    # the Gram matrix, λ, θ* and σ_head: the squash does not enter the posterior
    got, expected = squashed.laplace.state_dict(), affine.laplace.state_dict()
    names = [n for n, v in expected.items() if isinstance(v, torch.Tensor)]
    assert {"G_raw", "theta_map", "noise_variance", "prior_precision"} <= set(names)
    assert_all_close([got[n] for n in names], [expected[n] for n in names])
    observation = _obs_td(5)["observation"]
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        action = squashed(_obs_td(5))["action"]
        map_pre = affine(_obs_td(5))["action"]
    torch.testing.assert_close(action, squashed.actor(observation))
    torch.testing.assert_close(action, low + (high - low) * (torch.tanh(map_pre) + 1) / 2)
    zero = LaplaceEnsembleActor(squashed.actor, num_samples=0, sample_action=False)
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        torch.testing.assert_close(zero(_obs_td(5))["loc"], action)


def test_gradients_reach_the_head_through_the_squash_of_each_member():
    squashed, affine, low, high = _squashed_pair(num_samples=3)
    observation = _obs_td(4, scale=2.0)["observation"]
    squashed.member_actions(observation).sum().backward()
    pre = affine.member_actions(observation).detach()  # [M, B, A]
    # d/db of Σ_m Σ_b c + r tanh(b + ...) = Σ_m Σ_b r (1 - tanh²), r = (high - low) / 2
    expected = ((high - low) / 2 * (1 - torch.tanh(pre) ** 2)).sum((0, 1))
    torch.testing.assert_close(squashed.actor.head.bias.grad, expected)
