"""Offline data: transition layout, data sets, scores, returns-to-go and balanced replay.

Local generators, Minari loading, normalized scores, Monte-Carlo returns-to-go (Cal-QL's
bound) and OFF2ON's balanced replay.
"""

from torchrl_dual.data.balanced_replay import BalancedReplayBuffer
from torchrl_dual.data.cache import (
    default_cache_dir,
    load_cached_dataset,
    load_or_generate,
    save_cached_dataset,
)
from torchrl_dual.data.d4rl_references import (
    D4RL_HORIZONS,
    D4RL_REFERENCE_RETURNS,
    d4rl_references,
)
from torchrl_dual.data.frozenlake_dataset import (
    FROZENLAKE_GENERATOR_VERSION,
    generate_frozenlake_dataset,
    load_or_generate_frozenlake_dataset,
)
from torchrl_dual.data.goal_relabel import relabel_to_goal
from torchrl_dual.data.maze_controller import MazeWaypointController
from torchrl_dual.data.maze_dataset import (
    MAZE_GENERATOR_VERSION,
    compute_maze_references,
    generate_maze_dataset,
    load_or_generate_maze_dataset,
)
from torchrl_dual.data.mc_returns import episode_returns, monte_carlo_returns
from torchrl_dual.data.minari import default_observation_keys, load_minari_dataset
from torchrl_dual.data.minari_standins import STANDINS, write_standin_dataset
from torchrl_dual.data.minari_writer import collect_episodes, write_minari_dataset
from torchrl_dual.data.offline_dataset import OfflineDataset
from torchrl_dual.data.replay import to_replay_buffer
from torchrl_dual.data.scores import normalized_score
from torchrl_dual.data.transition_layout import (
    TRANSITION_KEYS,
    make_transitions,
    validate_transitions,
)

__all__ = [
    "D4RL_HORIZONS",
    "D4RL_REFERENCE_RETURNS",
    "d4rl_references",
    "relabel_to_goal",
    "STANDINS",
    "FROZENLAKE_GENERATOR_VERSION",
    "MAZE_GENERATOR_VERSION",
    "TRANSITION_KEYS",
    "BalancedReplayBuffer",
    "MazeWaypointController",
    "OfflineDataset",
    "collect_episodes",
    "compute_maze_references",
    "default_cache_dir",
    "default_observation_keys",
    "episode_returns",
    "generate_frozenlake_dataset",
    "generate_maze_dataset",
    "load_cached_dataset",
    "load_minari_dataset",
    "load_or_generate",
    "load_or_generate_frozenlake_dataset",
    "load_or_generate_maze_dataset",
    "make_transitions",
    "monte_carlo_returns",
    "normalized_score",
    "save_cached_dataset",
    "to_replay_buffer",
    "validate_transitions",
    "write_minari_dataset",
    "write_standin_dataset",
]
