"""D4RL's end of a Pen episode on Gymnasium-Robotics' ``AdroitHandPen`` (``env.protocol=d4rl``).

D4RL's pen (``hand_manipulation_suite/pen_v0.py``, ``step``) ends the episode when the pen
drops: ``done = True`` once the pen body's height ``obj_pos[2]`` is below 0.075, the step
that also pays the ``-5`` drop penalty. Gymnasium-Robotics' ``AdroitHandPen-v1`` keeps that
penalty but never terminates (its ``goal_failed`` line is commented out), so a dropped pen
goes on paying the penalty until the time limit. :class:`PenDropTermination` restores
D4RL's end; the reward is the env's own.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

D4RL_PEN_DROP_HEIGHT = 0.075
"""D4RL's pen ends the episode when the pen's height is below this (``pen_v0.py``)."""


class PenDropTermination(gym.Wrapper):
    """Terminates an ``AdroitHandPen`` episode when the pen drops, as D4RL's pen does.

    ``info["pen_dropped"]`` says whether the step ended that way.

    Args:
        env (gym.Env): an ``AdroitHandPen`` env (any wrapper of it).

    Examples:
        >>> import gymnasium as gym
        >>> from torchrl_dual.envs import register_robotics_envs
        >>> _ = register_robotics_envs()
        >>> env = PenDropTermination(gym.make("AdroitHandPen-v1", max_episode_steps=100))
        >>> _ = env.reset(seed=0)
        >>> _, _, terminated, _, info = env.step(env.action_space.sample() * 0)
        >>> terminated, info["pen_dropped"]
        (False, False)
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        pen = env.unwrapped
        if not hasattr(pen, "obj_body_id"):
            raise TypeError(
                f"PenDropTermination needs Gymnasium-Robotics' AdroitHandPen, got "
                f"{type(pen).__name__} (no 'obj_body_id')"
            )

    def height(self) -> float:
        """The pen body's height (D4RL's ``obj_pos[2]``)."""
        pen = self.env.unwrapped
        return float(pen.data.xpos[pen.obj_body_id][2])

    def step(self, action: Any):
        """Steps the env and terminates the episode if the pen dropped.

        Args:
            action: the hand's action.

        Returns:
            ``(observation, reward, terminated, truncated, info)``: ``terminated`` also when the
            pen is below D4RL's drop height, ``info["pen_dropped"]`` says whether it is.
        """
        obs, reward, terminated, truncated, info = self.env.step(action)
        dropped = self.height() < D4RL_PEN_DROP_HEIGHT
        return obs, reward, bool(terminated or dropped), truncated, {**info, "pen_dropped": dropped}
