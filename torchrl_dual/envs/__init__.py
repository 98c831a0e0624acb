"""Environment factories and the online dynamics shifts.

PointMaze (Gymnasium-Robotics), slippery Frozen-Lake, flat (normalized) observations for any
Gymnasium env, and the online dynamics shifts (:data:`SHIFTS`) of these and of the MuJoCo
locomotion robots (ODRL).
"""

from torchrl_dual.envs.d4rl_antmaze import (
    D4RL_ANTMAZE_MAPS,
    D4RLAntMazeTask,
    SingleGoalAntMaze,
)
from torchrl_dual.envs.d4rl_pen import PenDropTermination
from torchrl_dual.envs.flat_observation import FlatObservation, flat_dim, make_flat_env
from torchrl_dual.envs.frozenlake import (
    FROZENLAKE_MAPS,
    FROZENLAKE_NUM_ACTIONS,
    frozenlake_num_states,
    make_frozenlake_env,
)
from torchrl_dual.envs.frozenlake_mdp import (
    FROZENLAKE_HORIZON,
    FrozenLakeMDP,
    FrozenLakeSolution,
    frozenlake_mdp,
    frozenlake_optimal_policy,
    frozenlake_success_probability,
    frozenlake_transition_matrix,
    frozenlake_value_iteration,
)
from torchrl_dual.envs.locomotion_shifts import (
    KINEMATIC_JOINTS,
    LOCOMOTION_ROBOTS,
    LOCOMOTION_SHIFTS,
    LocomotionShift,
    locomotion_robot,
)
from torchrl_dual.envs.maze_cells import (
    POINTMAZE_IDS,
    default_max_episode_steps,
    goal_maze_map,
    open_cells,
    pointmaze_env_id,
    start_cells,
)
from torchrl_dual.envs.maze_xml import release_maze_xml
from torchrl_dual.envs.onehot_action import ContinuousOneHotAction
from torchrl_dual.envs.pointmaze import (
    flatten_pointmaze_obs,
    make_pointmaze_env,
    make_pointmaze_gym_env,
)
from torchrl_dual.envs.robotics import register_robotics_envs
from torchrl_dual.envs.shifts import (
    DEFAULT_SHIFT_ANGLE,
    SHIFTS,
    BiasedSlip,
    DynamicsShift,
    RotatedAction,
    ScaledPhysics,
    apply_shift,
    biased_slip_table,
    check_shift,
    shift_names,
)
from torchrl_dual.envs.vectorized import vectorized_env

__all__ = [
    "D4RL_ANTMAZE_MAPS",
    "D4RLAntMazeTask",
    "SingleGoalAntMaze",
    "PenDropTermination",
    "FlatObservation",
    "flat_dim",
    "make_flat_env",
    "DEFAULT_SHIFT_ANGLE",
    "KINEMATIC_JOINTS",
    "LOCOMOTION_ROBOTS",
    "LOCOMOTION_SHIFTS",
    "LocomotionShift",
    "locomotion_robot",
    "SHIFTS",
    "BiasedSlip",
    "DynamicsShift",
    "RotatedAction",
    "ScaledPhysics",
    "apply_shift",
    "biased_slip_table",
    "check_shift",
    "shift_names",
    "FROZENLAKE_HORIZON",
    "FROZENLAKE_MAPS",
    "FROZENLAKE_NUM_ACTIONS",
    "POINTMAZE_IDS",
    "ContinuousOneHotAction",
    "FrozenLakeMDP",
    "FrozenLakeSolution",
    "default_max_episode_steps",
    "flatten_pointmaze_obs",
    "goal_maze_map",
    "frozenlake_mdp",
    "frozenlake_num_states",
    "frozenlake_optimal_policy",
    "frozenlake_success_probability",
    "frozenlake_transition_matrix",
    "frozenlake_value_iteration",
    "make_frozenlake_env",
    "make_pointmaze_env",
    "make_pointmaze_gym_env",
    "open_cells",
    "register_robotics_envs",
    "release_maze_xml",
    "pointmaze_env_id",
    "start_cells",
    "vectorized_env",
]
