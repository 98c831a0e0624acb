"""Trajectory diffusion: schedules, denoisers, samplers and window sampling."""

from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser, SinusoidalTimeEmbedding
from torchrl_dual.diffusion.model import SAMPLERS, TrajectoryDiffusion
from torchrl_dual.diffusion.normalizer import Normalizer
from torchrl_dual.diffusion.schedule import SCHEDULES, NoiseSchedule
from torchrl_dual.diffusion.window import CONDITIONS, TrajectoryLayout
from torchrl_dual.diffusion.windows import WindowReplayBuffer

__all__ = [
    "CONDITIONS",
    "SAMPLERS",
    "SCHEDULES",
    "NoiseSchedule",
    "Normalizer",
    "ResidualMLPDenoiser",
    "SinusoidalTimeEmbedding",
    "TrajectoryDiffusion",
    "TrajectoryLayout",
    "WindowReplayBuffer",
]
