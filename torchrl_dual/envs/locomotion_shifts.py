"""ODRL dynamics shifts for the MuJoCo locomotion robots (Hopper, HalfCheetah, Walker2d v5).

The off-dynamics locomotion tasks of ODRL (Lyu et al. 2024, "ODRL: A Benchmark for
Off-Dynamics Reinforcement Learning", https://github.com/OffDynamicsRL/off-dynamics-rl,
``envs/mujoco/assets/*.xml``) change one physical property of the robot between the
data and the env the policy meets. DUAL (``dual.tex``, App. "ODRL MuJoCo Locomotion")
applies them online only at "shift level 2.0". Each shift here edits the env's own MuJoCo
model, so it reproduces ODRL's XML files on Gymnasium's v5 models; ``scale`` is ``s``:

* ``friction``: friction coefficients times ``s``. Hopper: the sliding friction of the
  robot's four geoms (the floor keeps 1.0); HalfCheetah and Walker2d: all three
  coefficients of every geom, floor included (ODRL scales their ``<default>`` geom, which
  the floor inherits, and Walker2d's per-geom values). ODRL levels 0.1, 0.5, 2.0, 5.0.
* ``gravity``: ``model.opt.gravity`` times ``s`` (ODRL levels 0.1, 0.5, 2.0, 5.0).
* ``kinematic``: a joint's range (both limits) divided by ``s``: Hopper's knee
  (``leg_joint``, -150..0 degrees), HalfCheetah's thighs (``bthigh``, ``fthigh``),
  Walker2d's thighs (``thigh_joint``, ``thigh_left_joint``, -150..0 degrees). ODRL's
  easy / medium / hard keep 0.8 / 0.5 / 0.2 of the range, i.e. ``s`` = 1.25 / 2 / 5;
  ``s = 2`` is ODRL's medium file exactly (ODRL's ``legjnt`` / ``thighjnt`` variants).
* ``morphology``: a limb shrunk by ``s``, the model recompiled (masses and inertias
  follow the geometry): Walker2d's shins (``leg_geom``, both legs, length 0.5 -> 0.5 / s;
  the knee moves down, the thigh grows, the foot stays at its height), HalfCheetah's torso
  (half-length 0.5 -> 0.5 / s; thighs and head move with its ends), Hopper's foot (length
  and radius / s, about the ankle). For Walker2d and HalfCheetah ODRL's easy / medium /
  hard are ``s`` = 1.25 / 2 / 5 (``morph_leg`` / ``morph_torso``), so ``s = 2`` is ODRL's
  medium file; ODRL's Hopper foot levels are 0.8 / 0.6 / 0.4 of the size (``s`` = 1.25 /
  1.67 / 2.5), so Hopper's ``s = 2`` lies between medium and hard.

ODRL's XMLs also move the foot body frame (``pos="0.13/2 0 0.1"`` -> ``"0.13 0 0"``);
in their global-coordinate files that only renames a frame, so it is not reproduced.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable

import gymnasium as gym
import numpy as np

LOCOMOTION_SHIFTS = ("friction", "gravity", "kinematic", "morphology")
"""The ODRL shifts of :class:`LocomotionShift`."""

LOCOMOTION_ROBOTS = {
    "HopperEnv": "hopper",
    "HalfCheetahEnv": "halfcheetah",
    "Walker2dEnv": "walker2d",
}
"""Gymnasium MuJoCo env class -> robot name."""

KINEMATIC_JOINTS = {
    "hopper": ("leg_joint",),
    "halfcheetah": ("bthigh", "fthigh"),
    "walker2d": ("thigh_joint", "thigh_left_joint"),
}
"""Robot -> the joints whose range ``kinematic`` divides by the scale."""


def locomotion_robot(env: gym.Env) -> str:
    """The robot of a Gymnasium MuJoCo locomotion env: hopper, halfcheetah or walker2d.

    Args:
        env (gym.Env): a Gymnasium MuJoCo Hopper, HalfCheetah or Walker2d env (any wrapper
            of it).

    Returns:
        str: ``"hopper"``, ``"halfcheetah"`` or ``"walker2d"``.

    Raises:
        ValueError: another env; the message lists the supported ones.

    Examples:
        >>> locomotion_robot(gym.make("HalfCheetah-v5"))
        'halfcheetah'
    """
    for cls in type(env.unwrapped).__mro__:  # Gymnasium's class or a subclass of it
        if cls.__name__ in LOCOMOTION_ROBOTS:
            return LOCOMOTION_ROBOTS[cls.__name__]
    supported = ", ".join(f"{cls} ({robot})" for cls, robot in LOCOMOTION_ROBOTS.items())
    raise ValueError(
        f"ODRL locomotion shifts support {supported}; got {type(env.unwrapped).__name__}."
    )


def _floats(element: ET.Element, attribute: str) -> np.ndarray:
    return np.array(element.get(attribute).split(), dtype=np.float64)


def _set(element: ET.Element, attribute: str, values) -> None:
    element.set(attribute, " ".join(repr(float(v)) for v in values))


def _named(root: ET.Element, tag: str, name: str) -> ET.Element:
    found = root.find(f".//{tag}[@name='{name}']")
    if found is None:
        raise ValueError(
            f"the model has no <{tag} name={name!r}>; morphology needs Gymnasium's v5 XML"
        )
    return found


def _shrink_walker2d_shins(root: ET.Element, scale: float) -> None:
    # Shin (leg_geom) length / s with its bottom end fixed: the knee moves down and the
    # thigh geom reaches it; the foot keeps its world height (ODRL walker2d_morph_leg).
    for side in ("", "_left"):
        thigh_geom = _named(root, "geom", f"thigh{side}_geom")
        leg, leg_joint = (
            _named(root, "body", f"leg{side}"),
            _named(root, "joint", f"leg{side}_joint"),
        )
        leg_geom, foot = (
            _named(root, "geom", f"leg{side}_geom"),
            _named(root, "body", f"foot{side}"),
        )
        leg_pos, foot_pos = _floats(leg, "pos"), _floats(foot, "pos")
        radius, half = _floats(leg_geom, "size")
        bottom = leg_pos[2] - half  # in the thigh frame
        new_half = half / scale
        new_leg_z = bottom + new_half
        knee = bottom + 2 * new_half
        _set(leg_geom, "size", (radius, new_half))
        _set(leg_joint, "pos", (0.0, 0.0, new_half))
        _set(leg, "pos", (leg_pos[0], leg_pos[1], new_leg_z))
        _set(foot, "pos", (foot_pos[0], foot_pos[1], foot_pos[2] + leg_pos[2] - new_leg_z))
        _set(thigh_geom, "size", (_floats(thigh_geom, "size")[0], -knee / 2))
        _set(thigh_geom, "pos", (0.0, 0.0, knee / 2))


def _shrink_halfcheetah_torso(root: ET.Element, scale: float) -> None:
    # Torso half-length / s; the thighs sit at its ends, the head keeps its offset from
    # the front end (ODRL halfcheetah_morph_torso).
    torso = _named(root, "geom", "torso")
    ends = _floats(torso, "fromto")
    half = ends[3]
    new_half = half / scale
    _set(torso, "fromto", (-new_half, *ends[1:3], new_half, *ends[4:]))
    head = _named(root, "geom", "head")
    head_pos = _floats(head, "pos")
    _set(head, "pos", (head_pos[0] - half + new_half, *head_pos[1:]))
    for name in ("bthigh", "fthigh"):
        body = _named(root, "body", name)
        pos = _floats(body, "pos")
        _set(body, "pos", (pos[0] / scale, *pos[1:]))


def _shrink_hopper_foot(root: ET.Element, scale: float) -> None:
    # Foot capsule length and radius / s, both ends pulled toward the ankle
    # (ODRL hopper_morph_foot scales the fromto ends about the ankle at x = 0).
    foot_geom, ankle = _named(root, "geom", "foot_geom"), _named(root, "joint", "foot_joint")
    pos, ankle_x = _floats(foot_geom, "pos"), _floats(ankle, "pos")[0]
    radius, half = _floats(foot_geom, "size")
    _set(foot_geom, "size", (radius / scale, half / scale))
    _set(foot_geom, "pos", (ankle_x + (pos[0] - ankle_x) / scale, *pos[1:]))


MORPHOLOGY_EDITS: dict[str, Callable[[ET.Element, float], None]] = {
    "hopper": _shrink_hopper_foot,
    "halfcheetah": _shrink_halfcheetah_torso,
    "walker2d": _shrink_walker2d_shins,
}
"""Robot -> the XML edit of ``morphology`` (the limb shrunk by the scale)."""


def _friction_geoms(model, robot: str) -> tuple[np.ndarray, slice]:
    """(geom ids, friction columns) that ``friction`` scales."""
    if robot == "hopper":  # ODRL sets the robot geoms' sliding friction only
        floor = model.geom("floor").id
        return np.array([g for g in range(model.ngeom) if g != floor]), slice(0, 1)
    return np.arange(model.ngeom), slice(0, 3)


def _shifted_below(env: gym.Env) -> bool:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, LocomotionShift):
            return True
        env = env.env
    return False


class LocomotionShift(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A MuJoCo locomotion env under one ODRL dynamics shift (module docstring).

    ``friction``, ``gravity`` and ``kinematic`` edit ``env.unwrapped.model`` in place;
    ``morphology`` recompiles the env's XML with the limb shrunk and swaps the model and
    data of ``env.unwrapped``. Either way only this env instance changes (each Gymnasium
    MuJoCo env compiles its own model) and ``env.spec`` keeps its id; the spec also records
    the shift (``additional_wrappers``), so ``gym.make(env.spec)`` rebuilds the shifted env.

    Args:
        env (gym.Env): ``Hopper-v5``, ``HalfCheetah-v5`` or ``Walker2d-v5`` (any kwargs).
        shift (str): one of :data:`LOCOMOTION_SHIFTS`.
        scale (float): the level ``s`` > 0; 2.0 is DUAL's "shift level 2.0".

    Examples:
        >>> env = LocomotionShift(gym.make("Hopper-v5"), "gravity", 2.0)
        >>> env.unwrapped.model.opt.gravity.tolist(), env.spec.id
        ([0.0, 0.0, -19.62], 'Hopper-v5')
    """

    def __init__(self, env: gym.Env, shift: str, scale: float = 2.0) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, shift=shift, scale=scale)
        super().__init__(env)
        if shift not in LOCOMOTION_SHIFTS:
            raise ValueError(
                f"Unknown locomotion shift {shift!r}. Valid names: {list(LOCOMOTION_SHIFTS)}."
            )
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}.")
        self.robot = locomotion_robot(env)
        self.shift, self.scale = shift, float(scale)
        import mujoco

        inner = env.unwrapped
        model = inner.model
        if shift == "friction":
            geoms, columns = _friction_geoms(model, self.robot)
            model.geom_friction[geoms, columns] *= self.scale
        elif shift == "gravity":
            model.opt.gravity[:] *= self.scale
        elif shift == "kinematic":
            for joint in KINEMATIC_JOINTS[self.robot]:
                model.jnt_range[model.joint(joint).id] /= self.scale
        else:
            if _shifted_below(env):  # recompiling from the XML would drop their edits
                raise ValueError("apply the morphology shift before any other locomotion shift")
            root = ET.parse(inner.fullpath).getroot()
            MORPHOLOGY_EDITS[self.robot](root, self.scale)
            model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
            model.vis.global_.offwidth = inner.model.vis.global_.offwidth
            model.vis.global_.offheight = inner.model.vis.global_.offheight
            inner.model, inner.data = model, mujoco.MjData(model)
            renderer = inner.mujoco_renderer  # its viewers hold the old model: drop them
            renderer.close()
            renderer.model, renderer.data, renderer._viewers, renderer.viewer = (
                model,
                inner.data,
                {},
                None,
            )
        # MuJoCo caches quantities derived from the model (as ScaledPhysics notes).
        mujoco.mj_setConst(inner.model, inner.data)
