"""Local D4RL-maze2d-like offline data for PointMaze, with score references and a disk cache.

Each episode resets the env, so start and task goal are drawn as at evaluation, and the
task goal is part of the observation and of the (sparse) reward. The behaviour policy,
however, is a noisy waypoint controller (:class:`MazeWaypointController`) that chases
its *own* random goal cells and picks a new one whenever it gets within
``goal_tolerance`` of the current one: like D4RL, the data covers the maze instead of
demonstrating the task.

References for normalized scores, averaged over ``num_reference_episodes`` evaluation
episodes: ``random_return`` (uniform actions in ``[-1, 1]``) and ``controller_return``
(the same noisy controller chasing the *true* goal).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from torchrl_dual.data.cache import default_cache_dir, load_or_generate
from torchrl_dual.data.maze_controller import MazeWaypointController
from torchrl_dual.data.offline_dataset import OfflineDataset
from torchrl_dual.data.transition_layout import make_transitions
from torchrl_dual.envs.maze_cells import default_max_episode_steps
from torchrl_dual.envs.pointmaze import flatten_pointmaze_obs, make_pointmaze_gym_env

MAZE_GENERATOR_VERSION = 1
"""Bump when the generated data changes for identical arguments (invalidates caches)."""


def _controller(
    env, action_noise: float, rng: np.random.Generator, avoid_cells: Sequence = ()
) -> MazeWaypointController:
    maze = env.unwrapped.maze
    return MazeWaypointController(
        maze.maze_map,
        maze_size_scaling=maze.maze_size_scaling,
        action_noise=action_noise,
        rng=rng,
        avoid_cells=avoid_cells,
    )


def _in_cells(ctrl: MazeWaypointController, positions: np.ndarray, cells: set) -> np.ndarray:
    """Whether each ``(x, y)`` of ``positions [N, 2]`` lies in one of ``cells``."""
    rows = np.floor((ctrl.y_center - positions[:, 1]) / ctrl.scaling).astype(int)
    cols = np.floor((positions[:, 0] + ctrl.x_center) / ctrl.scaling).astype(int)
    return np.array([(r, c) in cells for r, c in zip(rows, cols, strict=True)], dtype=bool)


def compute_maze_references(
    maze: str = "umaze",
    *,
    num_episodes: int = 50,
    seed: int = 0,
    max_episode_steps: int | None = None,
    action_noise: float = 0.5,
    continuing_task: bool = True,
    reward_type: str = "sparse",
    goal_cell: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Average returns and success rates of the random policy and of the goal-chasing controller.

    Args:
        maze (str): ``"umaze"``, ``"medium"`` or ``"large"``.

    Keyword Args:
        num_episodes (int): evaluation episodes per policy. Defaults to 50.
        seed (int): seed of the reference episodes (both policies see the same resets).
        max_episode_steps (int, optional): episode length; defaults to the registered one.
        action_noise (float): controller action-noise std. Defaults to 0.5.
        continuing_task (bool): as in :func:`~torchrl_dual.envs.make_pointmaze_env`.
        reward_type (str): ``"sparse"`` or ``"dense"``.
        goal_cell (sequence of int, optional): a fixed goal cell ``(row, col)``, as in
            :func:`~torchrl_dual.envs.make_pointmaze_env`; ``None``: random goals.

    Returns:
        a dict with ``random_return``, ``controller_return``, their standard deviations,
        ``random_success`` and ``controller_success`` (fraction of episodes that ever reached
        the goal) and ``num_episodes``.

    Examples:
        >>> refs = compute_maze_references("umaze", num_episodes=2, max_episode_steps=200)
        >>> refs["controller_return"] > refs["random_return"]
        True
    """
    env = make_pointmaze_gym_env(
        maze,
        max_episode_steps=max_episode_steps,
        continuing_task=continuing_task,
        reward_type=reward_type,
        goal_cell=goal_cell,
    )
    results: dict[str, Any] = {"num_episodes": int(num_episodes)}
    for name in ("random", "controller"):
        rng = np.random.default_rng([seed, 1])
        ctrl = _controller(env, action_noise, rng)
        returns, successes = [], []
        for ep in range(num_episodes):
            obs, _ = env.reset(seed=int(seed) * 100_003 + ep)
            total, success, done = 0.0, False, False
            while not done:
                if name == "random":
                    action = rng.uniform(-1.0, 1.0, size=2)
                else:
                    state = obs["observation"]
                    action = ctrl.act(state[:2], state[2:4], obs["desired_goal"])
                obs, reward, terminated, truncated, info = env.step(action)
                total += float(reward)
                success = success or bool(info.get("success", False))
                done = terminated or truncated
            returns.append(total)
            successes.append(success)
        results[f"{name}_return"] = float(np.mean(returns))
        results[f"{name}_return_std"] = float(np.std(returns))
        results[f"{name}_success"] = float(np.mean(successes))
    env.close()
    return results


def generate_maze_dataset(
    maze: str = "umaze",
    num_transitions: int = 100_000,
    *,
    seed: int = 0,
    max_episode_steps: int | None = None,
    action_noise: float = 0.5,
    goal_tolerance: float = 0.3,
    num_reference_episodes: int = 50,
    continuing_task: bool = True,
    reward_type: str = "sparse",
    goal_cell: Sequence[int] | None = None,
    avoid_cells: Sequence[Sequence[int]] | None = None,
) -> OfflineDataset:
    """Generates D4RL-maze2d-like PointMaze transitions (see the module docstring).

    Args:
        maze (str): ``"umaze"``, ``"medium"`` or ``"large"``.
        num_transitions (int): number of transitions; the last episode is cut (and marked
            ``truncated``) to hit the number exactly.

    Keyword Args:
        seed (int): seeds the env resets, the controller goals and noise, and the references.
        max_episode_steps (int, optional): episode length; defaults to the registered one
            (300 / 600 / 800), as at evaluation.
        action_noise (float): std of the Gaussian noise added to the controller's actions.
        goal_tolerance (float): distance at which the controller's own goal counts as reached.
        num_reference_episodes (int): episodes per reference policy (0 skips the references).
        continuing_task (bool): as in :func:`~torchrl_dual.envs.make_pointmaze_env`.
        reward_type (str): ``"sparse"`` (default) or ``"dense"``.
        goal_cell (sequence of int, optional): a fixed task goal cell ``(row, col)`` for
            every episode (the reward and the observation's goal); the controller still
            chases its own random goals. ``None`` (default): a random goal per episode.
        avoid_cells (sequence of (row, col), optional): cells the data never enter: the
            controller plans around them (:class:`MazeWaypointController`), an episode
            that starts in one is reset, and only noise can push the point mass across
            their border (``metadata["avoided_fraction"]`` counts those transitions).
            With ``goal_cell`` among them the data hold no reward: a task the online
            phase must explore (issue 29). The references stay the unconstrained
            controller's. ``None`` (default): every cell.

    Returns:
        An :class:`OfflineDataset` with ``reference_min = random_return`` and
        ``reference_max = controller_return``; ``metadata`` also holds success rates,
        the number of own goals reached and the generation time.

    Examples:
        >>> data = generate_maze_dataset("umaze", 500, max_episode_steps=100, num_reference_episodes=0)
        >>> len(data), data.obs_dim, data.action_dim, data.num_episodes
        (500, 6, 2, 5)
    """
    if num_transitions <= 0:
        raise ValueError(f"num_transitions must be positive, got {num_transitions}.")
    start = time.perf_counter()
    steps = max_episode_steps or default_max_episode_steps(maze)
    env = make_pointmaze_gym_env(
        maze,
        max_episode_steps=steps,
        continuing_task=continuing_task,
        reward_type=reward_type,
        goal_cell=goal_cell,
    )
    rng = np.random.default_rng([seed, 0])
    avoided = {(int(r), int(c)) for r, c in (avoid_cells or ())}
    ctrl = _controller(env, action_noise, rng, sorted(avoided))
    noise = rng.standard_normal((num_transitions, 2))

    def reset(**kwargs):  # a start outside the avoided cells
        for _ in range(100):
            obs, _ = env.reset(**kwargs)
            kwargs = {}
            if not _in_cells(ctrl, obs["observation"][None, :2], avoided)[0]:
                break
        return obs

    n = num_transitions
    obs_buf = np.empty((n, 6), np.float32)
    next_buf = np.empty((n, 6), np.float32)
    act_buf = np.empty((n, 2), np.float32)
    rew_buf = np.empty(n, np.float32)
    term_buf = np.zeros(n, bool)
    trunc_buf = np.zeros(n, bool)
    ep_buf = np.empty(n, np.int64)

    episode, goals_reached = 0, 0
    obs = reset(seed=int(seed))
    flat = flatten_pointmaze_obs(obs)
    state = obs["observation"]
    _, own_goal = ctrl.random_goal(exclude=ctrl.xy_to_cell(state[:2]))
    for t in range(n):
        action = ctrl.act(state[:2], state[2:4], own_goal, noise=noise[t])
        obs, reward, terminated, truncated, _ = env.step(action)
        next_flat = flatten_pointmaze_obs(obs)
        obs_buf[t], act_buf[t], next_buf[t] = flat, action, next_flat
        rew_buf[t], term_buf[t], ep_buf[t] = reward, terminated, episode
        trunc_buf[t] = truncated or (t == n - 1 and not terminated)
        state = obs["observation"]
        if terminated or truncated:
            episode += 1
            obs = reset()
            next_flat = flatten_pointmaze_obs(obs)
            state = obs["observation"]
            _, own_goal = ctrl.random_goal(exclude=ctrl.xy_to_cell(state[:2]))
        elif np.hypot(*(state[:2] - own_goal)) < goal_tolerance:
            goals_reached += 1
            _, own_goal = ctrl.random_goal(exclude=ctrl.xy_to_cell(state[:2]))
        flat = next_flat
    env.close()
    gen_seconds = time.perf_counter() - start

    metadata: dict[str, Any] = {
        "source": "pointmaze_local",
        "maze": maze,
        "seed": int(seed),
        "num_transitions": int(n),
        "max_episode_steps": int(steps),
        "action_noise": float(action_noise),
        "goal_tolerance": float(goal_tolerance),
        "continuing_task": bool(continuing_task),
        "reward_type": reward_type,
        "goal_cell": None if goal_cell is None else [int(v) for v in goal_cell],
        "avoid_cells": [list(cell) for cell in sorted(avoided)],
        "avoided_fraction": float(_in_cells(ctrl, obs_buf[:, :2], avoided).mean()),
        "generator_version": MAZE_GENERATOR_VERSION,
        "own_goals_reached": int(goals_reached),
        "reward_fraction": float((rew_buf > 0).mean()),
        "generation_seconds": round(gen_seconds, 3),
    }
    refs: dict[str, Any] = {}
    if num_reference_episodes > 0:
        start = time.perf_counter()
        refs = compute_maze_references(
            maze,
            num_episodes=num_reference_episodes,
            seed=int(seed) + 1,
            max_episode_steps=steps,
            action_noise=action_noise,
            continuing_task=continuing_task,
            reward_type=reward_type,
            goal_cell=goal_cell,
        )
        refs["reference_seconds"] = round(time.perf_counter() - start, 3)
        metadata["references"] = refs
    td = make_transitions(obs_buf, act_buf, next_buf, rew_buf, term_buf, trunc_buf, ep_buf)
    return OfflineDataset(
        td,
        reference_min=refs.get("random_return"),
        reference_max=refs.get("controller_return"),
        metadata=metadata,
    )


def load_or_generate_maze_dataset(
    maze: str = "umaze",
    num_transitions: int = 100_000,
    seed: int = 0,
    cache_dir: str | Path | None = None,
    *,
    verbose: bool = True,
    **kwargs: Any,
) -> OfflineDataset:
    """Loads the PointMaze data set from the disk cache, generating it on a miss.

    The entry lives in ``<cache_dir>/pointmaze-<maze>-n<num_transitions>-seed<seed>``
    (``pointmaze-<maze>-goal<row>_<col>-...`` with a fixed ``goal_cell``); it is
    regenerated when its recorded arguments or :data:`MAZE_GENERATOR_VERSION` differ.

    Args:
        maze (str): ``"umaze"``, ``"medium"`` or ``"large"``.
        num_transitions (int): number of transitions.
        seed (int): generation seed.
        cache_dir (str or Path, optional): defaults to :func:`default_cache_dir`.

    Keyword Args:
        verbose (bool): print the generation time on a cache miss. Defaults to ``True``.
        **kwargs: forwarded to :func:`generate_maze_dataset`.

    Examples:
        >>> import tempfile
        >>> root = tempfile.mkdtemp()
        >>> kw = dict(num_reference_episodes=1, verbose=False)
        >>> a = load_or_generate_maze_dataset("umaze", 300, 0, root, **kw)
        >>> b = load_or_generate_maze_dataset("umaze", 300, 0, root, **kw)
        >>> bool((a.transitions["observation"] == b.transitions["observation"]).all())
        True
    """
    from torchrl_dual.envs.maze_cells import goal_maze_map, pointmaze_env_id

    pointmaze_env_id(maze)  # fail fast on an unknown maze
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    goal_cell = kwargs.get("goal_cell")
    if goal_cell is None:  # the random-goal data keep their entries of before the option
        kwargs.pop("goal_cell", None)
    else:
        goal_maze_map(maze, goal_cell)  # fail fast on a wall or a cell outside the maze
        kwargs["goal_cell"] = [int(v) for v in goal_cell]
    avoid_cells = kwargs.pop("avoid_cells", None)
    if avoid_cells:  # data without those cells: entries of their own (older ones unchanged)
        kwargs["avoid_cells"] = sorted([int(r), int(c)] for r, c in avoid_cells)
    spec = {
        "generator": "pointmaze_local",
        "generator_version": MAZE_GENERATOR_VERSION,
        "maze": maze,
        "num_transitions": int(num_transitions),
        "seed": int(seed),
        **kwargs,
    }
    goal = "" if goal_cell is None else "-goal{}_{}".format(*kwargs["goal_cell"])
    if avoid_cells:
        goal += "-avoid" + "-".join("{}_{}".format(*cell) for cell in kwargs["avoid_cells"])
    path = root / f"pointmaze-{maze}{goal}-n{num_transitions}-seed{seed}"

    def generate() -> OfflineDataset:
        data = generate_maze_dataset(maze, num_transitions, seed=seed, **kwargs)
        if verbose:
            refs = data.metadata.get("references", {})
            print(
                f"Generated {num_transitions} PointMaze {maze} transitions in "
                f"{data.metadata['generation_seconds']:.1f} s (+{refs.get('reference_seconds', 0.0):.1f} s "
                f"for references), cached in {path}"
            )
        return data

    return load_or_generate(path, spec, generate)
