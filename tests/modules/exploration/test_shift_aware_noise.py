"""Unit tests of ShiftAwareNoise, the shift-aware exploration noise of DUAL Eq. 10."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Bounded, Composite
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules.exploration.shift_aware_noise import ShiftAwareNoise

OBS_DIM, ACT_DIM = 3, 2


def linear_model(observation, action):
    """ŝ' = s + B a with a fixed B (the 'original dynamics' of the tests)."""
    return observation + action @ torch.ones(ACT_DIM, OBS_DIM)


def make_td(*batch, shift=None, loc=0.3, scale=0.1):
    """Inputs whose previous step predicts ŝ_t at distance ``shift`` from s_t (along e_0)."""
    previous_observation = torch.randn(*batch, OBS_DIM)
    previous_action = torch.randn(*batch, ACT_DIM)
    observation = linear_model(previous_observation, previous_action)
    valid = torch.ones(*batch, 1, dtype=torch.bool)
    if shift is None:
        valid = ~valid
    else:
        offset = torch.as_tensor(shift, dtype=torch.float32).expand(*batch, 1)
        observation = observation + torch.cat([offset, torch.zeros(*batch, OBS_DIM - 1)], dim=-1)
    return TensorDict(
        observation=observation,
        previous_observation=previous_observation,
        previous_action=previous_action,
        previous_valid=valid,
        loc=torch.full((*batch, ACT_DIM), loc),
        scale=torch.full((*batch, ACT_DIM), scale),
        batch_size=batch,
    )


def test_noise_std_is_sqrt_of_variance_plus_weighted_shift_per_env():
    torch.manual_seed(0)
    noise = ShiftAwareNoise(linear_model, shift_weight=0.5)
    td = make_td(2, 20000, shift=torch.tensor([0.0, 2.0]).view(2, 1, 1))
    out = noise(td)
    torch.testing.assert_close(out["shift_distance"][:, 0], torch.tensor([[0.0], [2.0]]))
    expected = torch.tensor([0.1, (0.1**2 + 0.5 * 2.0) ** 0.5])  # Eq. 10
    measured = (out["action"] - 0.3).std(dim=(1, 2))
    torch.testing.assert_close(measured, expected, rtol=0.02, atol=0)
    torch.testing.assert_close(out["exploration_scale"][:, 0, 0], expected)
    assert (out["scale"] == 0.1).all()  # the Eq. 9 std is left untouched


def test_log_prob_is_normal_density_of_executed_action_summed_over_action_dim():
    noise = ShiftAwareNoise(linear_model, shift_weight=0.7, return_log_prob=True)
    out = noise(make_td(5, shift=0.4))
    dist = torch.distributions.Normal(out["loc"], (0.1**2 + 0.7 * 0.4) ** 0.5)
    torch.testing.assert_close(out["action_log_prob"], dist.log_prob(out["action"]).sum(-1))
    assert out["action_log_prob"].shape == (5,)
    assert "action_log_prob" not in ShiftAwareNoise(linear_model)(make_td(5, shift=0.4)).keys()


def test_zero_weight_reduces_to_plain_ensemble_gaussian_but_still_reports_d():
    torch.manual_seed(1)
    noise = ShiftAwareNoise(linear_model, shift_weight=0.0, return_log_prob=True)
    out = noise(make_td(40000, shift=5.0))
    torch.testing.assert_close(out["shift_distance"], torch.full((40000, 1), 5.0))
    torch.testing.assert_close(out["exploration_scale"], out["scale"])
    assert (out["action"] - 0.3).std().item() == pytest.approx(0.1, rel=0.02)
    dist = torch.distributions.Normal(out["loc"], out["scale"])
    torch.testing.assert_close(out["action_log_prob"], dist.log_prob(out["action"]).sum(-1))
    # λ = 0 needs no transition model at all (the "w/o shift-aware" ablation)
    bare = make_td(3).exclude("previous_observation", "previous_action", "previous_valid")
    out = ShiftAwareNoise(shift_weight=0.0)(bare)
    assert "shift_distance" not in out.keys()
    torch.testing.assert_close(out["exploration_scale"], out["scale"])


def test_no_previous_step_gives_zero_distance():
    torch.manual_seed(2)
    td = make_td(20000)  # previous_valid = False everywhere (just reset)
    td["previous_observation"] += 100.0  # whatever is carried is ignored
    out = ShiftAwareNoise(linear_model, shift_weight=10.0)(td)
    assert (out["shift_distance"] == 0).all()
    torch.testing.assert_close(out["exploration_scale"], out["scale"])
    assert (out["action"] - 0.3).std().item() == pytest.approx(0.1, rel=0.03)


def test_expected_observation_from_the_actor_takes_precedence_over_the_model():
    calls = []

    def model(observation, action):
        calls.append(1)
        return observation

    td = make_td(4, shift=1.0)
    td["expected_observation"] = td["observation"] + torch.tensor([0.0, 3.0, 4.0])
    out = ShiftAwareNoise(model)(td)
    torch.testing.assert_close(out["shift_distance"], torch.full((4, 1), 5.0))
    assert not calls
    # and no model is needed when the actor provides ŝ_t
    out = ShiftAwareNoise()(td.exclude("previous_observation", "previous_action"))
    torch.testing.assert_close(out["shift_distance"], torch.full((4, 1), 5.0))


@pytest.mark.parametrize(
    "mode", [ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN]
)
def test_deterministic_modes_return_loc_without_noise_or_model_call(mode):
    def model(observation, action):
        raise AssertionError("the transition model must not run in evaluation")

    noise = ShiftAwareNoise(model)
    with set_exploration_type(mode):
        out = noise(make_td(4, shift=3.0))
    torch.testing.assert_close(out["action"], out["loc"])
    for key in ("exploration_scale", "action_log_prob", "shift_distance"):
        assert key not in out.keys()


def test_action_is_projected_on_spec_given_late():
    torch.manual_seed(3)
    noise = ShiftAwareNoise(linear_model, shift_weight=1.0)
    out = noise(make_td(1000, shift=4.0))
    assert out["action"].abs().max() > 1.0  # no spec: no projection
    noise.spec = Bounded(-0.5, 0.5, shape=(ACT_DIM,))
    out = noise(make_td(1000, shift=4.0))
    assert out["action"].abs().max() <= 0.5
    assert (out["action"].abs() == 0.5).any()
    assert isinstance(noise.spec, Composite) and "action" in noise.spec.keys()


def test_box_clamp_matches_the_spec_projection_per_dimension():
    spec = Bounded(torch.tensor([-0.5, -2.0]), torch.tensor([1.0, 0.25]), shape=(ACT_DIM,))
    noise = ShiftAwareNoise(shift_weight=0.0, spec=spec)
    action = torch.randn(500, ACT_DIM) * 3
    torch.testing.assert_close(noise._project(action), spec.project(action.clone()))


def test_custom_keys_are_read_and_written():
    noise = ShiftAwareNoise(
        linear_model,
        observation_key="obs",
        loc_key=("policy", "mu"),
        scale_key=("policy", "sigma"),
        previous_observation_key="obs_before",
        previous_action_key="act_before",
        previous_valid_key="has_before",
        shift_key="d",
        action_key="act",
        exploration_scale_key="total_std",
        log_prob_key="logp",
        return_log_prob=True,
    )
    td = TensorDict(
        obs=torch.full((3, OBS_DIM), 6.0),
        obs_before=torch.zeros(3, OBS_DIM),
        act_before=torch.zeros(3, ACT_DIM),
        has_before=torch.ones(3, 1, dtype=torch.bool),
        policy=TensorDict(mu=torch.zeros(3, ACT_DIM), sigma=torch.ones(3, ACT_DIM), batch_size=[3]),
        batch_size=[3],
    )
    out = noise(td)
    assert {"act", "d", "total_std", "logp"} <= set(out.keys())
    torch.testing.assert_close(out["d"], torch.full((3, 1), 6.0 * 3**0.5))
    torch.testing.assert_close(out["total_std"], (1 + 0.5 * out["d"]).sqrt().expand(3, ACT_DIM))
    assert noise.in_keys[:3] == ["obs", ("policy", "mu"), ("policy", "sigma")]
    assert noise.in_keys[4:] == ["obs_before", "act_before", "has_before"]


def test_sequential_with_actor_overwrites_the_actor_sample():
    actor = TensorDictModule(
        lambda s: (s[..., :ACT_DIM], torch.full_like(s[..., :ACT_DIM], 0.1), s[..., :ACT_DIM]),
        ["observation"],
        ["loc", "scale", "action"],
    )
    policy = TensorDictSequential(actor, ShiftAwareNoise(linear_model))
    out = policy(make_td(4, shift=1.0).exclude("loc", "scale"))
    assert (out["action"] != out["loc"]).all()
    assert out["exploration_scale"].shape == (4, ACT_DIM)


def test_shift_weight_and_model_weights_are_in_state_dict():
    model = nn.Linear(OBS_DIM + ACT_DIM, OBS_DIM)
    noise = ShiftAwareNoise(lambda s, a: model(torch.cat([s, a], -1)), shift_weight=0.25)
    assert noise.state_dict()["shift_weight"] == 0.25

    class Model(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = model

        def forward(self, s, a):
            return self.net(torch.cat([s, a], -1))

    noise = ShiftAwareNoise(Model())
    assert "transition_model.net.weight" in noise.state_dict()
    assert noise(make_td(2, shift=1.0))["shift_distance"].shape == (2, 1)


@pytest.mark.parametrize(
    "edit, error, match",
    [
        (lambda td: td.exclude("loc"), KeyError, r"'loc'.*loc_key="),
        (lambda td: td.exclude("observation"), KeyError, r"'observation'.*observation_key="),
        (lambda td: td.exclude("scale"), KeyError, r"'scale'.*scale_key="),
        (
            lambda td: td.exclude("previous_action"),
            KeyError,
            r"'previous_action'.*PreviousTransition\(\)",
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
    ],
    ids=["missing-loc", "missing-obs", "missing-scale", "missing-prev", "scale", "ŝ", "obs-batch"],
)
def test_errors_name_key_shapes_and_fix(edit, error, match):
    td = edit(make_td(4, shift=1.0))
    with pytest.raises(error, match=match):
        ShiftAwareNoise(linear_model)(td)


def test_errors_for_bad_model_output_missing_source_weight_and_spec():
    bad = ShiftAwareNoise(lambda s, a: a)
    with pytest.raises(ValueError, match=r"'transition_model output' has shape \(4, 2\)"):
        bad(make_td(4, shift=1.0))
    with pytest.raises(KeyError, match=r"predict_transition=True.*transition_model=.*"):
        ShiftAwareNoise()(make_td(4, shift=1.0))
    with pytest.raises(ValueError, match="shift_weight"):
        ShiftAwareNoise(linear_model, shift_weight=-1.0)
    with pytest.raises(TypeError, match="callable"):
        ShiftAwareNoise("not a model")
    with pytest.raises(KeyError, match="action_key="):
        ShiftAwareNoise(linear_model, Composite(other=Bounded(-1, 1, shape=(ACT_DIM,))))


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
