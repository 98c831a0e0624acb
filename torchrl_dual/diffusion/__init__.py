"""Trajectory diffusion: schedules, denoisers, samplers and window sampling."""

from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser, SinusoidalTimeEmbedding
from torchrl_dual.diffusion.guidance import (
    NoisyWindowClassifier,
    classifier_guidance,
    density_ratio_loss,
)
from torchrl_dual.diffusion.model import LATENTS, SAMPLERS, TrajectoryDiffusion
from torchrl_dual.diffusion.normalizer import Normalizer
from torchrl_dual.diffusion.schedule import SCHEDULES, NoiseSchedule
from torchrl_dual.diffusion.trajectory_layout import CONDITIONS, TrajectoryLayout
from torchrl_dual.diffusion.window_replay_buffer import WindowReplayBuffer

__all__ = [
    "CONDITIONS",
    "LATENTS",
    "SAMPLERS",
    "SCHEDULES",
    "NoiseSchedule",
    "NoisyWindowClassifier",
    "Normalizer",
    "ResidualMLPDenoiser",
    "SinusoidalTimeEmbedding",
    "TrajectoryDiffusion",
    "TrajectoryLayout",
    "WindowReplayBuffer",
    "classifier_guidance",
    "density_ratio_loss",
]
