"""Tests of ``ShiftAwareNoise`` (``torchrl_dual/modules/exploration/shift_aware_noise.py``), the
shift-aware exploration noise of DUAL Eq. 10: ``a_t ~ N(μ, σ² + λ d_t)``, ``d_t = ‖ŝ_t − s_t‖``."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import transition_inputs

from torchrl_dual.modules import ShiftAwareNoise, TransitionModel

OBS_DIM, ACT_DIM = 3, 2


def make_td(*batch, shift=None, loc=0.3, scale=0.1):
    """Inputs whose ``expected_observation`` ŝ_t lies at distance ``shift`` from s_t (along
    e_0); without ``shift``, no ŝ_t at all."""
    observation = torch.randn(*batch, OBS_DIM)
    td = TensorDict(
        observation=observation,
        loc=torch.full((*batch, ACT_DIM), loc),
        scale=torch.full((*batch, ACT_DIM), scale),
        batch_size=batch,
    )
    if shift is not None:
        offset = torch.as_tensor(shift, dtype=torch.float32).expand(*batch, 1)
        direction = torch.cat([offset, torch.zeros(*batch, OBS_DIM - 1)], dim=-1)
        td["expected_observation"] = observation - direction
    return td


# ----------------------------------------------------------------------------- Eq. 10
def test_noise_std_is_sqrt_of_variance_plus_weighted_shift_per_env():
    torch.manual_seed(0)
    noise = ShiftAwareNoise(shift_weight=0.5)
    out = noise(make_td(2, 20000, shift=torch.tensor([0.0, 2.0]).view(2, 1, 1)))
    torch.testing.assert_close(out["shift_distance"][:, 0], torch.tensor([[0.0], [2.0]]))
    expected = torch.tensor([0.1, (0.1**2 + 0.5 * 2.0) ** 0.5])  # Eq. 10
    measured = (out["action"] - 0.3).std(dim=(1, 2))
    torch.testing.assert_close(measured, expected, rtol=0.02, atol=0)
    torch.testing.assert_close(out["exploration_scale"][:, 0, 0], expected)
    assert (out["scale"] == 0.1).all()  # the Eq. 9 std is left untouched


def test_the_action_is_loc_plus_the_total_std_times_a_standard_normal_draw():
    noise = ShiftAwareNoise(shift_weight=0.7)
    td = make_td(5, shift=0.4)
    torch.manual_seed(4)
    out = noise(td)
    torch.manual_seed(4)
    eps = torch.randn(5, ACT_DIM)
    std = (0.1**2 + 0.7 * 0.4) ** 0.5
    torch.testing.assert_close(out["action"], 0.3 + std * eps)


def test_log_prob_is_normal_density_of_executed_action_summed_over_action_dim():
    noise = ShiftAwareNoise(shift_weight=0.7, return_log_prob=True)
    out = noise(make_td(5, shift=0.4))
    dist = torch.distributions.Normal(out["loc"], (0.1**2 + 0.7 * 0.4) ** 0.5)
    torch.testing.assert_close(out["action_log_prob"], dist.log_prob(out["action"]).sum(-1))
    assert out["action_log_prob"].shape == (5,)
    assert "action_log_prob" in noise.out_keys
    assert "action_log_prob" not in ShiftAwareNoise()(make_td(5, shift=0.4)).keys()


def test_zero_weight_reduces_to_plain_ensemble_gaussian_but_still_reports_d():
    torch.manual_seed(1)
    noise = ShiftAwareNoise(shift_weight=0.0, return_log_prob=True)
    out = noise(make_td(40000, shift=5.0))
    torch.testing.assert_close(out["shift_distance"], torch.full((40000, 1), 5.0))
    torch.testing.assert_close(out["exploration_scale"], out["scale"])
    assert (out["action"] - 0.3).std().item() == pytest.approx(0.1, rel=0.02)
    dist = torch.distributions.Normal(out["loc"], out["scale"])
    torch.testing.assert_close(out["action_log_prob"], dist.log_prob(out["action"]).sum(-1))
    # λ = 0 needs no ŝ_t at all (the "w/o shift-aware" ablation)
    out = ShiftAwareNoise(shift_weight=0.0)(make_td(3))
    torch.testing.assert_close(out["shift_distance"], torch.zeros(3, 1))  # its out_keys
    torch.testing.assert_close(out["exploration_scale"], out["scale"])


def test_zero_variance_and_zero_shift_stay_finite():
    out = ShiftAwareNoise(return_log_prob=True)(make_td(4, shift=0.0, scale=0.0))
    assert torch.isfinite(out["action_log_prob"]).all()
    torch.testing.assert_close(out["action"], out["loc"], atol=1e-5, rtol=0)


@pytest.mark.parametrize(
    "mode", [ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN]
)
def test_deterministic_modes_return_loc_without_noise_or_shift(mode):
    noise = ShiftAwareNoise(Bounded(-0.2, 0.2, shape=(ACT_DIM,)))
    with set_exploration_type(mode):
        out = noise(make_td(4))  # no ŝ_t needed either
    assert torch.equal(out["action"], out["loc"].clamp(-0.2, 0.2))
    # its out_keys, as in every mode: no noise (scale 0) and no shift (d_t = 0)
    assert (out["exploration_scale"] == 0).all() and (out["shift_distance"] == 0).all()
    assert "action_log_prob" not in out.keys()  # not asked for (return_log_prob=False)


# ----------------------------------------------------------------------------- ŝ_t upstream
def test_a_transition_model_upstream_gives_d_t_and_zero_after_a_reset(make_model):
    transition = TransitionModel(make_model(num_steps=1))
    policy = TensorDictSequential(transition, ShiftAwareNoise(shift_weight=10.0))
    observation, previous_observation, previous_action = transition_inputs(6)
    valid = torch.tensor([[True], [False]] * 3)
    td = make_td(6)
    td.update(
        dict(
            observation=observation,
            previous_observation=previous_observation,
            previous_action=previous_action,
            previous_valid=valid,
        )
    )
    out = policy(td)
    predicted = transition.predict(previous_observation, previous_action)
    distance = (predicted - observation).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(out["shift_distance"], torch.where(valid, distance, 0.0))
    assert (out["shift_distance"][valid] > 0).all()
    std = (0.1**2 + 10.0 * out["shift_distance"]).sqrt().expand(6, ACT_DIM)
    torch.testing.assert_close(out["exploration_scale"], std)


def test_sequential_with_actor_overwrites_the_actor_sample():
    actor = TensorDictModule(
        lambda s: (s[..., :ACT_DIM], torch.full_like(s[..., :ACT_DIM], 0.1), s[..., :ACT_DIM]),
        ["observation"],
        ["loc", "scale", "action"],
    )
    policy = TensorDictSequential(actor, ShiftAwareNoise())
    out = policy(make_td(4, shift=1.0).exclude("loc", "scale"))
    assert (out["action"] != out["loc"]).all()
    assert out["exploration_scale"].shape == (4, ACT_DIM)


# ----------------------------------------------------------------------------- projection
def test_action_is_projected_on_spec_given_late():
    torch.manual_seed(3)
    noise = ShiftAwareNoise(shift_weight=1.0)
    out = noise(make_td(1000, shift=4.0))
    assert out["action"].abs().max() > 1.0  # no spec: no projection
    noise.spec = Bounded(-0.5, 0.5, shape=(ACT_DIM,))
    out = noise(make_td(1000, shift=4.0))
    assert out["action"].abs().max() <= 0.5
    assert (out["action"].abs() == 0.5).any()
    assert isinstance(noise.spec, Composite) and "action" in noise.spec.keys()


def test_box_clamp_matches_the_spec_projection_per_dimension():
    spec = Bounded(torch.tensor([-0.5, -2.0]), torch.tensor([1.0, 0.25]), shape=(ACT_DIM,))
    noise = ShiftAwareNoise(spec, shift_weight=0.0)
    action = torch.randn(500, ACT_DIM) * 3
    torch.testing.assert_close(noise._project(action), spec.project(action.clone()))


def test_a_spec_that_is_no_box_projects_with_its_own_project():
    """Specs other than a continuous box go through ``spec.project`` (here the identity of
    an unbounded spec), not the clamp."""
    noise = ShiftAwareNoise(Unbounded(shape=(ACT_DIM,)), shift_weight=0.5)
    assert noise._box is None
    action = torch.randn(50, ACT_DIM) * 5
    torch.testing.assert_close(noise._project(action), action)
    torch.manual_seed(0)
    assert noise(make_td(7, shift=1.0))["action"].shape == (7, ACT_DIM)


def test_action_projection_stores_the_executed_one_hot_action():
    def one_hot(action):
        return torch.nn.functional.one_hot(action.argmax(-1), action.shape[-1]).to(action.dtype)

    noise = ShiftAwareNoise(shift_weight=0.0, action_projection=one_hot)
    td = TensorDict(
        {
            "observation": torch.zeros(64, 3),
            "loc": torch.tensor([0.1, 0.9, 0.2, 0.0]).expand(64, 4),
            "scale": torch.full((64, 4), 0.3),
        },
        [64],
    )
    action = noise(td)["action"]
    assert torch.equal(action.sum(-1), torch.ones(64))
    assert set(action.unique().tolist()) <= {0.0, 1.0}


# ----------------------------------------------------------------------------- keys, state
def test_custom_keys_are_read_and_written():
    noise = ShiftAwareNoise(
        observation_key="obs",
        loc_key=("policy", "mu"),
        scale_key=("policy", "sigma"),
        expected_observation_key="obs_hat",
        shift_key="d",
        action_key="act",
        exploration_scale_key="total_std",
        log_prob_key="logp",
        return_log_prob=True,
    )
    td = TensorDict(
        obs=torch.full((3, OBS_DIM), 6.0),
        obs_hat=torch.zeros(3, OBS_DIM),
        policy=TensorDict(mu=torch.zeros(3, ACT_DIM), sigma=torch.ones(3, ACT_DIM), batch_size=[3]),
        batch_size=[3],
    )
    out = noise(td)
    assert {"act", "d", "total_std", "logp"} <= set(out.keys())
    torch.testing.assert_close(out["d"], torch.full((3, 1), 6.0 * 3**0.5))
    torch.testing.assert_close(out["total_std"], (1 + 0.5 * out["d"]).sqrt().expand(3, ACT_DIM))
    assert noise.in_keys == ["obs", ("policy", "mu"), ("policy", "sigma"), "obs_hat"]
    assert noise.out_keys == ["act", "d", "total_std", "logp"]


def test_shift_weight_and_floor_are_the_only_state():
    noise = ShiftAwareNoise(shift_weight=0.25, shift_floor=0.5)
    assert list(noise.state_dict()) == ["shift_weight", "shift_floor"]
    assert noise.state_dict()["shift_weight"] == 0.25
    restored = ShiftAwareNoise(shift_weight=0.0)  # λ = 0: no shift term until the load
    restored.load_state_dict(noise.state_dict())
    out = restored(make_td(4, shift=2.0))
    torch.testing.assert_close(
        out["exploration_scale"], (0.01 + 0.25 * (2.0 - 0.5)) ** 0.5 * torch.ones(4, 2)
    )
    with pytest.raises(KeyError, match="expected_observation"):  # λ > 0 now needs ŝ_t
        restored(make_td(4))
    plain = ShiftAwareNoise(shift_weight=0.5)
    plain.load_state_dict(ShiftAwareNoise(shift_weight=0.0).state_dict())
    assert plain(make_td(4))["shift_distance"].eq(0).all()  # λ = 0 now: ŝ_t not needed
    assert repr(restored) == (
        "ShiftAwareNoise(shift_weight=0.25, shift_floor=0.5, extra_variance=0, "
        "in_keys=['observation', 'loc', 'scale', 'expected_observation'], "
        "out_keys=['action', 'shift_distance', 'exploration_scale'], "
        "projected=False)"
    )


def test_the_floor_adds_only_the_excess_of_d_over_it_and_leaves_d_as_logged():
    """Variance σ² + λ max(d − d_0, 0): d below the floor adds nothing (the plain ensemble
    Gaussian), d above it adds λ (d − d_0); the logged shift_distance is d itself. A floor
    set after construction (``fill_``, as the recipe does) acts the same way."""
    torch.manual_seed(0)
    noise = ShiftAwareNoise(shift_weight=0.5)
    noise.shift_floor.fill_(1.0)
    d = torch.tensor([0.0, 0.6, 1.0, 3.0]).view(4, 1, 1)
    out = noise(make_td(4, 20000, shift=d))
    torch.testing.assert_close(out["shift_distance"][:, 0], d[:, 0])
    expected = torch.tensor([0.1, 0.1, 0.1, (0.1**2 + 0.5 * 2.0) ** 0.5])
    torch.testing.assert_close(out["exploration_scale"][:, 0, 0], expected)
    measured = (out["action"] - 0.3).std(dim=(1, 2))
    torch.testing.assert_close(measured, expected, rtol=0.02, atol=0)
    with pytest.raises(ValueError, match=r"shift_floor \(d_0, subtracted from d_t\) must be >= 0"):
        ShiftAwareNoise(shift_floor=-0.1)


def test_extra_variance_adds_a_constant_to_every_actions_variance():
    """``v_c`` (beyond the paper) adds to σ² with or without ŝ_t: with λ = 0 and no
    transition model it is a state-independent noise of the same size as λ d_t (the control
    for Eq. 10); with λ > 0 both add, and the measured action std follows. It is not state:
    the state dict keeps only λ and d_0."""
    torch.manual_seed(0)
    constant = ShiftAwareNoise(shift_weight=0.0, extra_variance=0.15)
    out = constant(make_td(2, 20000))  # no expected_observation at all
    expected = (0.1**2 + 0.15) ** 0.5
    torch.testing.assert_close(out["exploration_scale"], torch.full((2, 20000, 2), expected))
    torch.testing.assert_close(
        (out["action"] - 0.3).std(dim=(1, 2)), torch.full((2,), expected), rtol=0.02, atol=0
    )
    both = ShiftAwareNoise(shift_weight=0.5, extra_variance=0.15)
    out = both(make_td(3, shift=2.0))
    torch.testing.assert_close(
        out["exploration_scale"], torch.full((3, 2), (0.1**2 + 0.15 + 0.5 * 2.0) ** 0.5)
    )
    assert list(both.state_dict()) == ["shift_weight", "shift_floor"]
    assert "extra_variance=0.15" in repr(both)
    plain = ShiftAwareNoise(shift_weight=0.5)(make_td(3, shift=2.0))  # v_c = 0: Eq. 10
    torch.testing.assert_close(
        plain["exploration_scale"], torch.full((3, 2), (0.1**2 + 0.5 * 2.0) ** 0.5)
    )
    with pytest.raises(ValueError, match=r"extra_variance .* must be >= 0, got -0.1"):
        ShiftAwareNoise(extra_variance=-0.1)


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "edit, error, match",
    [
        (lambda td: td.exclude("loc"), KeyError, r"'loc'.*loc_key="),
        (lambda td: td.exclude("observation"), KeyError, r"'observation'.*observation_key="),
        (lambda td: td.exclude("scale"), KeyError, r"'scale'.*scale_key="),
        (
            lambda td: td.exclude("expected_observation"),
            KeyError,
            r"'expected_observation'.*Place a TransitionModel before ShiftAwareNoise.*"
            r"PreviousTransition\(\).*shift_weight=0",
        ),
        (
            lambda td: td.set("scale", torch.ones(4, 1)),
            ValueError,
            r"'scale' has shape \(4, 1\), expected \(4, 2\).*expand",
        ),
        (
            lambda td: td.set("expected_observation", torch.ones(4, 1)),
            ValueError,
            r"'expected_observation' has shape \(4, 1\), expected \(4, 3\)",
        ),
        (
            lambda td: td.set("observation", torch.ones(4, 1, OBS_DIM)),
            ValueError,
            r"'observation' has batch dims \(4, 1\), expected \(4,\)",
        ),
        (
            lambda td: TensorDict(loc=torch.tensor(0.0), batch_size=[]),
            ValueError,
            r"trailing action dim",
        ),
    ],
    ids=["missing-loc", "missing-obs", "missing-scale", "missing-ŝ", "scale", "ŝ", "obs", "scalar"],
)
def test_errors_name_key_shapes_and_fix(edit, error, match):
    td = edit(make_td(4, shift=1.0))
    with pytest.raises(error, match=match):
        ShiftAwareNoise()(td)


def test_bad_weight_and_spec_are_rejected():
    with pytest.raises(ValueError, match=r"shift_weight \(λ of Eq. 10\) must be >= 0, got -1.0"):
        ShiftAwareNoise(shift_weight=-1.0)
    with pytest.raises(TypeError, match="spec must be a TorchRL TensorSpec.*TransitionModel"):
        ShiftAwareNoise(lambda s, a: s)  # the old transition_model argument
    with pytest.raises(KeyError, match="action_key="):
        ShiftAwareNoise(Composite(other=Bounded(-1, 1, shape=(ACT_DIM,))))
