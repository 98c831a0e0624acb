"""Online-only dynamics shifts: one table, :data:`SHIFTS`, applied to Gymnasium envs.

A shift changes what the same state and action lead to. It is applied to the online env
and to the evaluation env, never to the env the offline data comes from, so an offline
policy meets dynamics it has not seen. Every shift works on the raw Gymnasium env
(:func:`apply_shift`); the TorchRL factories wrap the shifted Gymnasium env, and the
exact Frozen-Lake model (:mod:`~torchrl_dual.envs.frozenlake_mdp`) rewrites its
transition table with the same function as the env (:func:`biased_slip_table`).

* ``none`` (every env kind): nothing changes.
* ``friction``, ``gravity``, ``kinematic``, ``morphology`` (locomotion: Hopper,
  HalfCheetah, Walker2d v5): ODRL's shifts at level ``scale`` (default 2.0), see
  :mod:`~torchrl_dual.envs.locomotion_shifts`.
* ``rotation`` (pointmaze): the action ``(ax, ay)`` is rotated by ``angle`` degrees
  (counter-clockwise) before the env clips and executes it.
* ``damping`` (pointmaze): MuJoCo ``model.dof_damping`` of the point's two slide joints
  is multiplied by ``scale``.
* ``mass`` (pointmaze): MuJoCo ``model.body_mass`` of the point is multiplied by ``scale``.
* ``biased_slip`` (frozenlake): a slip always turns counter-clockwise of the intended
  move (left -> down, down -> right, right -> up, up -> left): the intended move keeps
  its probability ``success_rate``, the counter-clockwise neighbour gets the rest.
* ``biased_slip_cw`` (frozenlake): the same with every slip turning clockwise.

Which side matters depends on the map: on ``8x8`` the policy optimal for the offline
data succeeds 0.934 online without a shift, 0.0 under ``biased_slip`` and 0.977 under
``biased_slip_cw`` (the optimum is 1.0 under both); on ``4x4`` it is the other way round
(0.692 -> 0.0 under ``biased_slip_cw``, 1.0 under ``biased_slip``). Measured by
``benchmarks/studies/shifts.py`` (``docs/recipe.md``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from torchrl_dual.envs.locomotion_shifts import LocomotionShift


@dataclass(frozen=True)
class DynamicsShift:
    """One entry of :data:`SHIFTS`.

    Args:
        kinds (tuple of str): the env kinds (``"pointmaze"``, ``"frozenlake"``,
            ``"locomotion"``) it applies to.
        wrap (callable): ``(env, angle, scale) -> env``, the shifted Gymnasium env.
        doc (str): one line saying what changes.
        default_scale (float, optional): the scale used when none is given (PointMaze: sized
            so that the offline expert keeps at most half of its score, see
            ``docs/recipe.md``; locomotion: DUAL's ODRL "shift level 2.0").

    Examples:
        >>> from torchrl_dual.envs import SHIFTS
        >>> shift = SHIFTS["mass"]
        >>> shift.kinds, shift.default_scale, shift.doc
        (('pointmaze',), 20.0, 'point mass multiplied by env.shift_scale')
    """

    kinds: tuple[str, ...]
    wrap: Callable[[gym.Env, float, float | None], gym.Env]
    doc: str
    default_scale: float | None = None


class RotatedAction(gym.ActionWrapper):
    """Rotates a 2-D action by ``angle`` degrees (counter-clockwise) before the env sees it.

    Examples:
        >>> from torchrl_dual.envs import make_pointmaze_gym_env
        >>> env = make_pointmaze_gym_env("umaze", shift="rotation", shift_angle=90)
        >>> isinstance(env, RotatedAction), env.action([1.0, 0.0]).round(6).tolist()
        (True, [0.0, 1.0])
    """

    def __init__(self, env: gym.Env, angle: float) -> None:
        super().__init__(env)
        self.angle = float(angle)
        rad = math.radians(self.angle)
        self.rotation = np.array([[math.cos(rad), -math.sin(rad)], [math.sin(rad), math.cos(rad)]])

    def action(self, action):
        """The rotated action ``R(angle) a``.

        Args:
            action: the policy's 2-D action.

        Returns:
            ``R @ action``, float64 ``[2]``.
        """
        return self.rotation @ np.asarray(action, dtype=np.float64)


def _point_model(env: gym.Env):
    inner = env.unwrapped
    if not hasattr(inner, "point_env"):
        raise ValueError(f"this shift needs a PointMaze env, got {type(inner).__name__}")
    return inner.point_env.model


class ScaledPhysics(gym.Wrapper):
    """Multiplies a MuJoCo model field of the PointMaze point by ``scale`` (in place).

    Args:
        env (gym.Env): a PointMaze env (``env.unwrapped.point_env`` is its MuJoCo env).
        field (str): ``"dof_damping"`` (both slide joints) or ``"body_mass"`` (the point).
        scale (float): the factor, > 0.

    Examples:
        >>> from torchrl_dual.envs import make_pointmaze_gym_env
        >>> def point_mass(env):
        ...     model = env.unwrapped.point_env.model
        ...     return model.body_mass[model.body("particle").id]
        >>> env = make_pointmaze_gym_env("umaze", shift="mass", shift_scale=2.0)
        >>> isinstance(env, ScaledPhysics)
        True
        >>> round(float(point_mass(env) / point_mass(make_pointmaze_gym_env("umaze"))), 6)
        2.0
    """

    def __init__(self, env: gym.Env, field: str, scale: float) -> None:
        super().__init__(env)
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}.")
        self.field, self.scale = field, float(scale)
        model = _point_model(env)
        if field == "dof_damping":
            model.dof_damping[:] *= self.scale
        elif field == "body_mass":
            body = model.body("particle").id
            model.body_mass[body] *= self.scale
        else:
            raise ValueError(f"unknown field {field!r}; use dof_damping or body_mass")
        import mujoco

        # MuJoCo caches quantities derived from the model (e.g. the constant mass matrix
        # of the slide joints): without this a changed body_mass has no effect.
        mujoco.mj_setConst(model, env.unwrapped.point_env.data)


def biased_slip_table(P: dict, success_rate: float, clockwise: bool = False) -> dict:
    """Gymnasium Frozen-Lake's ``P[s][a]`` with every slip sent to one side.

    Slippery ``FrozenLakeEnv`` lists, for a non-terminal cell, the outcomes of the moves
    ``(a - 1) % 4``, ``a``, ``(a + 1) % 4`` (0=left, 1=down, 2=right, 3=up), with
    probabilities ``(1 - p) / 2, p, (1 - p) / 2``. ``(a + 1) % 4`` is the
    counter-clockwise turn of ``a`` on the map (left -> down, down -> right, right -> up,
    up -> left) and ``(a - 1) % 4`` the clockwise one; the biased slip gives one of them
    the whole ``1 - p``. Terminal cells are unchanged.

    Args:
        P (dict): ``P[s][a]``, the ``(probability, next state, reward, terminated)`` outcomes
            of slippery Frozen-Lake (``FrozenLakeEnv.P``).
        success_rate (float): ``p``, the probability of the intended move.
        clockwise (bool): send the slips clockwise instead of counter-clockwise.

    Returns:
        dict: a new table; ``P`` is left as it is.

    Raises:
        ValueError: ``P`` is not slippery (a move without three outcomes).

    Examples:
        >>> from gymnasium.envs.toy_text.frozen_lake import FrozenLakeEnv
        >>> P = FrozenLakeEnv(map_name="4x4", success_rate=0.75).P
        >>> biased_slip_table(P, 0.75)[0][2]  # RIGHT from the start: slips go up (stay)
        [(0.75, 1, 0, False), (0.25, 0, 0, False)]
        >>> biased_slip_table(P, 0.75, clockwise=True)[0][2]  # slips go down
        [(0.25, 4, 0, False), (0.75, 1, 0, False)]
    """
    table: dict = {}
    for s, by_action in P.items():
        table[s] = {}
        for a, outcomes in by_action.items():
            if len(outcomes) == 1:  # hole or goal: absorbing
                table[s][a] = list(outcomes)
                continue
            if len(outcomes) != 3:
                raise ValueError("biased_slip needs slippery Frozen-Lake (3 outcomes per move)")
            intended = outcomes[1]
            if clockwise:
                table[s][a] = [
                    (1.0 - success_rate, *outcomes[0][1:]),
                    (success_rate, *intended[1:]),
                ]
            else:
                table[s][a] = [
                    (success_rate, *intended[1:]),
                    (1.0 - success_rate, *outcomes[2][1:]),
                ]
    return table


class BiasedSlip(gym.Wrapper):
    """Slippery Frozen-Lake whose slips all turn to one side (rewrites ``P`` in place).

    Args:
        env (gym.Env): a slippery ``FrozenLake-v1``.
        clockwise (bool): slips turn clockwise instead of counter-clockwise.

    Examples:
        >>> env = BiasedSlip(gym.make("FrozenLake-v1", is_slippery=True))
        >>> env.unwrapped.P[0][2]  # RIGHT from the start: a third right, the rest up (stay)
        [(0.3333333333333333, 1, 0, False), (0.6666666666666667, 0, 0, False)]
    """

    def __init__(self, env: gym.Env, clockwise: bool = False) -> None:
        super().__init__(env)
        inner = env.unwrapped
        if not hasattr(inner, "P") or not hasattr(inner, "desc"):
            raise ValueError(f"biased_slip needs a Frozen-Lake env, got {type(inner).__name__}")
        start = int(np.argmax(inner.initial_state_distrib))
        probs = [p for p, *_ in inner.P[start][0]]
        if len(probs) != 3:
            raise ValueError("biased_slip needs slippery Frozen-Lake (is_slippery=True)")
        self.clockwise = bool(clockwise)
        inner.P = biased_slip_table(inner.P, probs[1], clockwise=self.clockwise)


LOCOMOTION_DOCS = {
    "friction": "ODRL friction: the robot's geom friction multiplied by env.shift_scale",
    "gravity": "ODRL gravity: the gravity vector multiplied by env.shift_scale",
    "kinematic": "ODRL kinematic: the knee (hopper) or thigh joints' range divided by "
    "env.shift_scale (ODRL easy / medium / hard = 1.25 / 2 / 5)",
    "morphology": "ODRL morphology: the foot (hopper), torso (halfcheetah) or shins (walker2d) "
    "shrunk by env.shift_scale (ODRL easy / medium / hard = 1.25 / 2 / 5; hopper foot "
    "1.25 / 1.67 / 2.5)",
}
"""ODRL locomotion shift -> its :data:`SHIFTS` doc line (:class:`LocomotionShift`)."""


def _locomotion(shift: str) -> Callable[[gym.Env, float, float | None], gym.Env]:
    return lambda env, angle, scale: LocomotionShift(env, shift, scale)


SHIFTS: dict[str, DynamicsShift] = {
    "none": DynamicsShift(
        ("pointmaze", "frozenlake", "antmaze", "locomotion", "adroit"),
        lambda env, angle, scale: env,
        "nothing",
    ),
    "rotation": DynamicsShift(
        ("pointmaze",),
        lambda env, angle, scale: RotatedAction(env, angle),
        "actions rotated by env.shift_angle degrees",
    ),
    "damping": DynamicsShift(
        ("pointmaze",),
        lambda env, angle, scale: ScaledPhysics(env, "dof_damping", scale),
        "joint damping multiplied by env.shift_scale",
        default_scale=150.0,
    ),
    "mass": DynamicsShift(
        ("pointmaze",),
        lambda env, angle, scale: ScaledPhysics(env, "body_mass", scale),
        "point mass multiplied by env.shift_scale",
        default_scale=20.0,
    ),
    "biased_slip": DynamicsShift(
        ("frozenlake",),
        lambda env, angle, scale: BiasedSlip(env),
        "slips always turn counter-clockwise of the intended move",
    ),
    "biased_slip_cw": DynamicsShift(
        ("frozenlake",),
        lambda env, angle, scale: BiasedSlip(env, clockwise=True),
        "slips always turn clockwise of the intended move",
    ),
    **{
        name: DynamicsShift(("locomotion",), _locomotion(name), doc, default_scale=2.0)
        for name, doc in LOCOMOTION_DOCS.items()
    },
}
"""Shift name -> :class:`DynamicsShift`."""

DEFAULT_SHIFT_ANGLE = 60.0
"""Rotation of ``rotation`` in degrees when none is given."""


def shift_names(kind: str) -> tuple[str, ...]:
    """The shifts an env kind supports, ``"none"`` first.

    Args:
        kind (str): ``"pointmaze"``, ``"frozenlake"``, ``"antmaze"``, ``"locomotion"`` or
            ``"adroit"``.

    Returns:
        tuple[str, ...]: the names of :data:`SHIFTS` that apply to ``kind``.

    Examples:
        >>> shift_names("pointmaze"), shift_names("frozenlake")
        (('none', 'rotation', 'damping', 'mass'), ('none', 'biased_slip', 'biased_slip_cw'))
        >>> shift_names("locomotion")
        ('none', 'friction', 'gravity', 'kinematic', 'morphology')
    """
    return tuple(name for name, shift in SHIFTS.items() if kind in shift.kinds)


def check_shift(shift: str, kind: str | None = None) -> DynamicsShift:
    """The :data:`SHIFTS` entry of ``shift``; ``ValueError`` listing the options otherwise.

    Args:
        shift (str): a name of :data:`SHIFTS`.
        kind (str, optional): the env kind ``shift`` must apply to (``"pointmaze"``, ...);
            any kind if omitted.

    Returns:
        DynamicsShift: the entry.

    Raises:
        ValueError: an unknown name, or one that does not apply to ``kind``.

    Examples:
        >>> check_shift("mass", "pointmaze").default_scale
        20.0
    """
    names = tuple(SHIFTS) if kind is None else shift_names(kind)
    if shift not in names:
        where = "" if kind is None else f" for {kind}"
        raise ValueError(f"Unknown shift {shift!r}{where}. Valid names: {list(names)}.")
    return SHIFTS[shift]


def apply_shift(
    env: gym.Env,
    shift: str = "none",
    *,
    angle: float | None = None,
    scale: float | None = None,
    kind: str | None = None,
) -> gym.Env:
    """Returns ``env`` under the dynamics shift ``shift`` (``env`` itself for ``"none"``).

    Args:
        env (gym.Env): the raw Gymnasium env (PointMaze, Frozen-Lake or a MuJoCo locomotion env).
        shift (str): a :data:`SHIFTS` name.

    Keyword Args:
        angle (float, optional): degrees for ``rotation``; defaults to 60.
        scale (float, optional): factor for ``damping`` / ``mass``, level of the locomotion
            shifts; defaults to the entry's ``default_scale``.
        kind (str, optional): the env kind, to reject a shift made for another env.

    Examples:
        >>> from gymnasium.envs.toy_text.frozen_lake import FrozenLakeEnv
        >>> env = apply_shift(FrozenLakeEnv(map_name="4x4", success_rate=0.75), "biased_slip")
        >>> env.unwrapped.P[0][1]  # DOWN from the start: down w.p. 3/4, slip right
        [(0.75, 4, 0, False), (0.25, 1, 0, False)]
    """
    entry = check_shift(shift, kind)
    if angle is None:
        angle = DEFAULT_SHIFT_ANGLE
    if scale is None:
        scale = entry.default_scale
    return entry.wrap(env, float(angle), scale)
