"""Tests for the Laplace ensemble policy of DUAL (Eq. 8 fit, Eq. 9 policy).

With a transition model (Eq. 10, collector): ``test_laplace_ensemble_transition.py``;
over a squashed actor: ``test_laplace_ensemble_squash.py``."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ValueOperator
from toy import ENSEMBLE_ACTION_DIM as ACT
from toy import ENSEMBLE_OBS_DIM as OBS
from toy import assert_all_close
from toy import ensemble_actor as _actor
from toy import ensemble_observation_td as _obs_td
from toy import ensemble_training_data as _training_data
from toy import fitted_ensemble as _fitted_policy

from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor
from torchrl_dual.objectives.weighted_map_actor import WeightedMAPActorLoss

ACTOR_KINDS = ("linear_head", "planner")


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


@pytest.mark.parametrize("fused", [False, True], ids=["sgd", "fused-adam"])
@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_inference_members_follow_resampling_and_optimizer_steps(kind, fused, make_model):
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
    if fused:  # as the recipe's actors train (fused Adam moves no version counter itself)
        optimizer = torch.optim.Adam(policy.actor.parameters(), lr=0.5, fused=True)
    else:
        optimizer = torch.optim.SGD(policy.actor.parameters(), lr=0.5)
    (policy.actor(observation) ** 2).sum().backward()
    optimizer.step()
    assert not torch.allclose(both(), second)


@pytest.mark.parametrize("kind", ACTOR_KINDS)
def test_the_acting_scale_follows_each_update_of_the_aleatoric_std(kind, make_model):
    """σ̄² is cached on the action path (no autograd) and must follow ``log_std``."""
    policy = _fitted_policy(kind, make_model, num_samples=3)
    td = _obs_td(4)

    def scale_without_and_with_autograd():
        with torch.no_grad():
            cached = policy(td.clone())["scale"]
        fresh = policy(td.clone())["scale"]
        assert fresh.requires_grad  # with autograd, σ̄ stays differentiable in log σ̄
        return cached, fresh.detach()

    before, fresh = scale_without_and_with_autograd()
    torch.testing.assert_close(before, fresh)
    optimizer = torch.optim.SGD([policy.actor.log_std], lr=1.0)
    policy.actor.log_std.grad = -torch.ones_like(policy.actor.log_std)
    optimizer.step()  # log σ̄ + 1, in place
    after, fresh = scale_without_and_with_autograd()
    torch.testing.assert_close(after, fresh)
    epistemic = policy(td.clone())["epistemic_variance"].detach()
    torch.testing.assert_close(after**2 - epistemic, (before**2 - epistemic) * torch.e**2)


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


@pytest.mark.parametrize("batches", [[], [TensorDict({"observation": torch.zeros(0, OBS)}, [0])]])
def test_fit_laplace_on_no_data_says_what_data_it_needs(make_model, batches):
    policy = LaplaceEnsembleActor(_actor("linear_head", make_model))
    with pytest.raises(
        ValueError,
        match=r"^fit_laplace got no data: pass TensorDict batches of states under "
        r"'observation', e\.g\. \[offline_data\] \(Eq\. 8 fits on the whole data set\)\.$",
    ):
        policy.fit_laplace(batches)


def test_without_sample_action_the_ensemble_leaves_the_draw_to_the_next_module(make_model):
    policy = _fitted_policy("linear_head", make_model)
    policy.sample_action = False
    with set_exploration_type(ExplorationType.RANDOM):
        out = policy(_obs_td(5))
    torch.testing.assert_close(out["action"], out["loc"])
    assert "action_log_prob" not in out.keys()
    assert (out["epistemic_variance"] > 0).all()


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
