"""ODRL locomotion shifts (``torchrl_dual.envs.locomotion_shifts``): each changes what the
same MuJoCo state and action lead to, edits the model to ODRL's level-2.0 ("medium") XML
values, and leaves every other env instance alone."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from torchrl_dual.envs import KINEMATIC_JOINTS, LocomotionShift, apply_shift, shift_names

ROBOTS = {"hopper": "Hopper-v5", "halfcheetah": "HalfCheetah-v5", "walker2d": "Walker2d-v5"}
SHIFTS = [name for name in shift_names("locomotion") if name != "none"]


def make(robot: str, shift: str = "none") -> gym.Env:
    return apply_shift(gym.make(ROBOTS[robot]), shift, kind="locomotion")


def probe_state(robot: str, shift: str) -> tuple[np.ndarray, np.ndarray]:
    """A state where ``shift`` matters: on the floor and sliding forward (friction), and
    for ``kinematic`` with the restricted joints outside their shifted range (at 0.75 of
    an original limit; this lifts the feet, so only then)."""
    env = gym.make(ROBOTS[robot]).unwrapped
    env.reset(seed=0)
    for _ in range(30):  # fall onto the floor
        env.step(np.zeros(env.action_space.shape))
    qpos, qvel = env.data.qpos.copy(), env.data.qvel.copy()
    qvel[0] += 1.0
    assert env.data.ncon > 0  # touching the floor
    for joint in KINEMATIC_JOINTS[robot] if shift == "kinematic" else ():
        low, high = env.model.jnt_range[env.model.joint(joint).id]
        qpos[env.model.jnt_qposadr[env.model.joint(joint).id]] = 0.75 * (
            low if -low > high else high
        )
    return qpos, qvel


def rollout(env: gym.Env, qpos: np.ndarray, qvel: np.ndarray, steps: int = 5) -> np.ndarray:
    env.reset(seed=0)
    env.unwrapped.set_state(qpos, qvel)
    action = 0.5 * np.cos(np.arange(env.action_space.shape[0]))
    return np.stack([env.step(action)[0] for _ in range(steps)])


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_each_shift_changes_the_next_states_and_none_changes_nothing(robot):
    for shift in SHIFTS:
        qpos, qvel = probe_state(robot, shift)
        plain = rollout(make(robot), qpos, qvel)
        np.testing.assert_array_equal(rollout(make(robot, "none"), qpos, qvel), plain)
        shifted = rollout(make(robot, shift), qpos, qvel)
        assert np.abs(shifted - plain).max() > 0.2, (robot, shift)


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_level_one_is_the_identity_for_every_shift(robot):
    # the edits are nothing but the scaling: s = 1 leaves the dynamics as they were
    # (bit-identical in place; the recompiled morphology differs by float rounding of the
    # recomputed positions only)
    qpos, qvel = probe_state(robot, "kinematic")
    plain = rollout(gym.make(ROBOTS[robot]), qpos, qvel)
    for shift in SHIFTS:
        env = apply_shift(gym.make(ROBOTS[robot]), shift, scale=1.0, kind="locomotion")
        atol = 1e-9 if shift == "morphology" else 0.0
        np.testing.assert_allclose(
            rollout(env, qpos, qvel), plain, rtol=0, atol=atol, err_msg=shift
        )


def original_and_shifted(robot: str, shift: str):
    """The models of two envs of one id, the second shifted after the first was made."""
    plain = gym.make(ROBOTS[robot])
    shifted = make(robot, shift)
    return plain.unwrapped.model, shifted.unwrapped.model


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_friction_doubles_odrls_geoms_and_leaves_the_unshifted_env_alone(robot):
    plain, shifted = original_and_shifted(robot, "friction")
    reference = gym.make(ROBOTS[robot]).unwrapped.model.geom_friction
    np.testing.assert_array_equal(plain.geom_friction, reference)  # the first env is untouched
    expected = 2.0 * reference
    if robot == "hopper":  # ODRL: robot geoms' sliding friction only, the floor keeps 1.0
        expected = reference.copy()
        expected[1:, 0] *= 2.0
        assert plain.geom("floor").id == 0 and plain.geom_friction[0, 0] == 1.0
        assert shifted.geom_friction[shifted.geom("foot_geom").id, 0] == 4.0  # ODRL 2.0 -> 4.0
    np.testing.assert_allclose(shifted.geom_friction, expected, rtol=1e-12)


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_gravity_doubles(robot):
    plain, shifted = original_and_shifted(robot, "gravity")
    np.testing.assert_allclose(plain.opt.gravity, [0, 0, -9.81])
    np.testing.assert_allclose(shifted.opt.gravity, [0, 0, -19.62])


# ODRL's *_kinematic_{legjnt,thighjnt}_medium.xml ranges, in the XML's units.
KINEMATIC_MEDIUM = {
    "hopper": {"leg_joint": np.radians([-75.0, 0.0])},
    "halfcheetah": {"bthigh": [-0.26, 0.525], "fthigh": [-0.5, 0.35]},
    "walker2d": {
        "thigh_joint": np.radians([-75.0, 0.0]),
        "thigh_left_joint": np.radians([-75.0, 0.0]),
    },
}


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_kinematic_restricts_the_joint_to_odrls_medium_range(robot):
    plain, shifted = original_and_shifted(robot, "kinematic")
    for joint, expected in KINEMATIC_MEDIUM[robot].items():
        np.testing.assert_allclose(shifted.jnt_range[shifted.joint(joint).id], expected, atol=1e-12)
        np.testing.assert_allclose(plain.jnt_range[plain.joint(joint).id], 2 * np.asarray(expected))
    changed = np.flatnonzero(np.any(plain.jnt_range != shifted.jnt_range, axis=1))
    assert sorted(plain.joint(j).name for j in changed) == sorted(KINEMATIC_MEDIUM[robot])


def capsule_mass(radius: float, half_length: float, density: float = 1000.0) -> float:
    return density * (math.pi * radius**2 * 2 * half_length + 4 / 3 * math.pi * radius**3)


def world_span(model, geom: str) -> tuple[np.ndarray, np.ndarray]:
    """The two end points (x, z) of a capsule's axis at the model's reference pose."""
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    g = model.geom(geom).id
    axis = data.geom_xmat[g].reshape(3, 3)[:, 2] * model.geom_size[g, 1]
    return (data.geom_xpos[g] - axis)[[0, 2]], (data.geom_xpos[g] + axis)[[0, 2]]


def test_walker2d_morphology_is_odrls_medium_shins():
    plain, shifted = original_and_shifted("walker2d", "morphology")
    for side in ("", "_left"):  # ODRL medium: thigh 1.05 -> 0.35, shin 0.35 -> 0.1
        assert sorted(z for _, z in world_span(shifted, f"thigh{side}_geom")) == pytest.approx(
            [0.35, 1.05]
        )
        assert sorted(z for _, z in world_span(shifted, f"leg{side}_geom")) == pytest.approx(
            [0.1, 0.35]
        )
        assert sorted(z for _, z in world_span(plain, f"leg{side}_geom")) == pytest.approx(
            [0.1, 0.6]
        )
        # inertia follows the geometry: the shin body is one capsule of density 1000
        assert shifted.body(f"leg{side}").mass[0] == pytest.approx(capsule_mass(0.04, 0.125))
        assert plain.body(f"leg{side}").mass[0] == pytest.approx(capsule_mass(0.04, 0.25))
    for geom in ("foot_geom", "foot_left_geom"):  # the feet do not move
        np.testing.assert_allclose(world_span(shifted, geom), world_span(plain, geom), atol=1e-12)


def test_halfcheetah_morphology_is_odrls_medium_torso():
    plain, shifted = original_and_shifted("halfcheetah", "morphology")
    # ODRL medium: torso fromto -.25..0.25, head at x .35, thighs at -.25 / .25
    torso = shifted.geom("torso").id
    assert shifted.geom_size[torso, 1] == pytest.approx(0.25)
    assert plain.geom_size[plain.geom("torso").id, 1] == pytest.approx(0.5)
    assert shifted.geom_pos[shifted.geom("head").id, 0] == pytest.approx(0.35)
    assert shifted.body("bthigh").pos[0] == pytest.approx(-0.25)
    assert shifted.body("fthigh").pos[0] == pytest.approx(0.25)
    # settotalmass = 14 keeps the total; the shorter torso carries less of it
    assert shifted.body_subtreemass[1] == pytest.approx(plain.body_subtreemass[1])
    assert shifted.body("torso").mass[0] < plain.body("torso").mass[0]


def test_hopper_morphology_halves_the_foot_about_the_ankle():
    plain, shifted = original_and_shifted("hopper", "morphology")
    # original foot axis x in [-0.13, 0.26] (ankle at x = 0), radius 0.06
    (x0, _), (x1, _) = world_span(plain, "foot_geom")
    assert sorted([x0, x1]) == pytest.approx([-0.13, 0.26])
    (x0, z0), (x1, z1) = world_span(shifted, "foot_geom")
    assert sorted([x0, x1]) == pytest.approx([-0.065, 0.13]) and [z0, z1] == pytest.approx(
        [0.1, 0.1]
    )
    assert shifted.geom_size[shifted.geom("foot_geom").id, 0] == pytest.approx(0.03)
    assert shifted.body("foot").mass[0] == pytest.approx(capsule_mass(0.03, 0.0975))


def test_morphology_keeps_the_spec_and_the_env_steps_and_resets():
    env = make("walker2d", "morphology")
    assert env.spec.id == "Walker2d-v5" and isinstance(env, LocomotionShift)
    obs, _ = env.reset(seed=1)
    assert obs.shape == (17,)
    assert np.isfinite(env.step(env.action_space.sample())[0]).all()
    assert env.unwrapped.mujoco_renderer.model is env.unwrapped.model
    again = gym.make(env.spec)  # the spec records the shift
    leg = again.unwrapped.model.geom("leg_geom").id
    assert again.unwrapped.model.geom_size[leg, 1] == env.unwrapped.model.geom_size[leg, 1] == 0.125


def test_unsupported_robot_or_kind_is_a_clear_error():
    with pytest.raises(
        ValueError, match=r"support HopperEnv \(hopper\), HalfCheetahEnv.*got SwimmerEnv"
    ):
        apply_shift(gym.make("Swimmer-v5"), "gravity", kind="locomotion")
    with pytest.raises(ValueError, match=r"Unknown shift 'friction' for pointmaze"):
        apply_shift(gym.make("Hopper-v5"), "friction", kind="pointmaze")
    with pytest.raises(ValueError, match=r"Unknown locomotion shift 'mass'"):
        LocomotionShift(gym.make("Hopper-v5"), "mass")
    with pytest.raises(ValueError, match="apply the morphology shift before"):
        LocomotionShift(make("hopper", "gravity"), "morphology")
    with pytest.raises(ValueError, match="scale must be > 0"):
        LocomotionShift(gym.make("Hopper-v5"), "gravity", 0.0)
