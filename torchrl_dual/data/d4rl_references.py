"""D4RL's published reference returns and time limits.

The numbers ``env.protocol=d4rl`` scores and runs the paper's benchmarks with (the paper
follows CORL, which uses D4RL's).

Sources (Farama-Foundation/D4RL, the last commit of 2024-11):

* :data:`D4RL_REFERENCE_RETURNS`: ``d4rl/infos.py`` ``REF_MIN_SCORE`` / ``REF_MAX_SCORE``:
  ``<robot>-random-v0`` for every locomotion data set (``-v1``/``-v2`` keys are copied from
  them there), ``<task>-human-v0`` for every Adroit data set (``-v1`` keys copied likewise),
  ``0`` / ``1`` for every ``antmaze-*-v2``. The normalized score is
  ``100 * (return - min) / (max - min)`` (``offline_env.get_normalized_score`` times 100, as
  CORL reports it).
* :data:`D4RL_HORIZONS`: the ``max_episode_steps`` of the registrations:
  ``d4rl/hand_manipulation_suite/__init__.py`` (``MAX_STEPS``: pen 100, door / hammer /
  relocate 200) and the Gym MuJoCo locomotion envs (1000).

Minari's data sets differ: ``mujoco/*`` carry no references at all, and ``D4RL/pen/*-v2``
episodes last 200 steps while its references are D4RL's 100-step ones (docs/reproducing.md).
"""

from __future__ import annotations

D4RL_REFERENCE_RETURNS: dict[str, tuple[float, float]] = {
    "hopper": (-20.272305, 3234.3),
    "halfcheetah": (-280.178953, 12135.0),
    "walker2d": (1.629008, 4592.3),
    "pen": (96.262799, 3076.8331017826877),
    "door": (-56.512833, 2880.5693087298737),
    "hammer": (-274.856578, 12794.134825156867),
    "relocate": (-6.425911, 4233.877797728884),
    "antmaze": (0.0, 1.0),
}
"""Task -> D4RL's ``(REF_MIN_SCORE, REF_MAX_SCORE)``: random and expert returns."""

D4RL_HORIZONS: dict[str, int] = {
    "hopper": 1000,
    "halfcheetah": 1000,
    "walker2d": 1000,
    "pen": 100,
    "door": 200,
    "hammer": 200,
    "relocate": 200,
}
"""Task -> D4RL's ``max_episode_steps`` (AntMaze's, per maze, are
:data:`~torchrl_dual.envs.d4rl_antmaze.D4RL_ANTMAZE_HORIZONS`)."""


def d4rl_references(task: str) -> tuple[float, float]:
    """D4RL's ``(random, expert)`` returns of ``task``.

    Args:
        task (str): a key of :data:`D4RL_REFERENCE_RETURNS` (e.g. ``"hopper"``).

    Returns:
        tuple[float, float]: the random and the expert policy's returns, the 0 and 100 of
        D4RL's normalized score.

    Raises:
        KeyError: D4RL has no references for ``task``; the message lists the known tasks.

    Examples:
        >>> d4rl_references("hopper")
        (-20.272305, 3234.3)
    """
    if task not in D4RL_REFERENCE_RETURNS:
        known = sorted(D4RL_REFERENCE_RETURNS)
        raise KeyError(f"D4RL has no reference returns for {task!r}; known: {known}")
    return D4RL_REFERENCE_RETURNS[task]
