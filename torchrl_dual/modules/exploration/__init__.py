"""Exploration on the policy side: DUAL's shift-aware variance and DACER's entropy-regulated noise.

The shift-aware variance of Eq. 10 (DUAL) and the entropy-regulated noise of the ``dacer``
baseline with its Gaussian-mixture entropy estimate.
"""

from torchrl_dual.modules.exploration.entropy_regulator import (
    EntropyRegulatedNoise,
    dacer_target_entropy,
    sampled_entropy,
)
from torchrl_dual.modules.exploration.gmm_entropy import (
    GaussianMixtureFit,
    fit_gaussian_mixture,
    mixture_entropy,
)
from torchrl_dual.modules.exploration.shift_aware_noise import ShiftAwareNoise

__all__ = [
    "EntropyRegulatedNoise",
    "GaussianMixtureFit",
    "ShiftAwareNoise",
    "dacer_target_entropy",
    "fit_gaussian_mixture",
    "mixture_entropy",
    "sampled_entropy",
]
