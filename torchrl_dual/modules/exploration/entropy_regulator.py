"""DACER's entropy regulator: additive Gaussian noise whose scale ``α`` follows an entropy target.

DACER (Wang et al. 2024, "Diffusion Actor-Critic with Entropy Regulator", NeurIPS)
explores with the diffusion policy's sample plus Gaussian noise,

``a = a_diffusion + noise_scale · α · ε``,  ``ε ~ N(0, I)``,

then clips it to the action box (reference code ``relax/network/dacer.py``,
``get_action``: ``noise_scale = 0.15`` for Humanoid and HalfCheetah, ``0.1`` for the
other MuJoCo tasks). ``log α`` is learned by SAC's temperature loss with the policy's
entropy ``Ĥ`` estimated from samples (:func:`sampled_entropy`, a Gaussian mixture
fitted to ``K`` actions per state, :mod:`~torchrl_dual.modules.exploration.gmm_entropy`):

``L(log α) = −log α · (H̄ − Ĥ)``,  ``∂L/∂ log α = Ĥ − H̄``,

so gradient descent raises ``α`` (more noise, more entropy) while ``Ĥ`` is below the
target ``H̄`` and lowers it above (``relax/algorithm/dacer.py``: Adam at ``3e-2``,
``Ĥ`` re-estimated and ``log α`` stepped every 10 000 updates, ``α_0 = 3``,
``H̄ = −0.9 · dim(A)``). The estimate is of the exploration distribution itself (noise
and clip included), which closes the loop. Evaluation drops the noise (DACER's
deterministic action sets ``log α = −∞``).

:class:`EntropyRegulatedNoise` holds ``log α`` (a parameter, so it is checkpointed with
the module), the noise scale and ``H̄`` (buffers); it adds the noise under
``ExplorationType.RANDOM`` (or unset) only, as TorchRL's ``AdditiveGaussianModule``.
"""

from __future__ import annotations

import math

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual._utils import is_deterministic, read_key
from torchrl_dual.modules.exploration.gmm_entropy import mixture_entropy

__all__ = ["EntropyRegulatedNoise", "dacer_target_entropy", "sampled_entropy"]


def dacer_target_entropy(action_dim: int) -> float:
    """DACER's entropy target ``H̄ = −0.9 · dim(A)`` (``relax/network/dacer.py``).

    Args:
        action_dim (int): ``dim(A)``.

    Returns:
        float: ``H̄``.

    Examples:
        >>> dacer_target_entropy(2)
        -1.8
    """
    return -0.9 * action_dim


class EntropyRegulatedNoise(TensorDictModuleBase):
    """Adds ``noise_scale · α · ε`` to the action under RANDOM exploration (DACER).

    Place it after a stochastic actor in a :class:`~tensordict.nn.TensorDictSequential`
    and clamp or project the action after it. Under DETERMINISTIC / MODE / MEAN it
    leaves the action as it is.

    Args:
        target_entropy (float): ``H̄`` of :meth:`alpha_loss` (DACER:
            :func:`dacer_target_entropy`).
        noise_scale (float): multiplies ``α``; ``> 0``. Defaults to 0.1.
        init_alpha (float): ``α`` at construction, ``> 0``. Defaults to 3.0 (DACER's).

    Keyword Args:
        action_key (NestedKey): the action to perturb. Defaults to ``"action"``.
        device (torch.device, optional): device of ``log α`` and the buffers.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> noise = EntropyRegulatedNoise(target_entropy=-1.8, noise_scale=0.1, init_alpha=3.0)
        >>> td = noise(TensorDict(action=torch.zeros(10000, 2), batch_size=[10000]))
        >>> round(float(td["action"].std()), 1)  # noise_scale · α
        0.3
        >>> loss = noise.alpha_loss(torch.tensor(-3.0))  # Ĥ below H̄
        >>> loss.backward()
        >>> noise.log_alpha.grad  # Ĥ - H̄ < 0: descent raises α
        tensor(-1.2000)
    """

    def __init__(
        self,
        target_entropy: float,
        noise_scale: float = 0.1,
        init_alpha: float = 3.0,
        *,
        action_key: NestedKey = "action",
        device: torch.device | None = None,
    ) -> None:
        for name, value in (("noise_scale", noise_scale), ("init_alpha", init_alpha)):
            if not float(value) > 0:
                raise ValueError(f"EntropyRegulatedNoise: {name} must be > 0, got {value}.")
        if not math.isfinite(float(target_entropy)):
            raise ValueError(
                f"EntropyRegulatedNoise: target_entropy must be finite, got {target_entropy}."
            )
        self.action_key = action_key
        self.in_keys = [action_key]
        self.out_keys = [action_key]
        super().__init__()
        self.log_alpha = nn.Parameter(torch.tensor(math.log(init_alpha), device=device))
        self.register_buffer("noise_scale", torch.tensor(float(noise_scale), device=device))
        self.register_buffer("target_entropy", torch.tensor(float(target_entropy), device=device))

    @property
    def alpha(self) -> Tensor:
        """``α = exp(log α)`` (detached)."""
        return self.log_alpha.detach().exp()

    @property
    def std(self) -> Tensor:
        """The noise's std per action dimension, ``noise_scale · α`` (detached)."""
        return self.noise_scale * self.alpha

    def alpha_loss(self, entropy: Tensor) -> Tensor:
        """The temperature's loss ``L(log α) = −log α · (H̄ − Ĥ)`` for the estimate ``entropy``.

        ``Ĥ`` is detached; a batch of estimates is averaged. Its gradient ``Ĥ − H̄``
        lowers ``α`` when the policy's entropy exceeds the target and raises it
        below.
        """
        gap = self.target_entropy - entropy.detach().mean()
        return -self.log_alpha * gap

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``action ← action + noise_scale · α · ε`` (RANDOM or unset exploration)."""
        if is_deterministic():
            return tensordict
        action = read_key(
            tensordict,
            self.action_key,
            "EntropyRegulatedNoise (the actor's action)",
            "Place it after an actor that writes it, or pass action_key=<your key>.",
        )
        std = self.std.to(action.dtype)
        tensordict.set(self.action_key, action + std * torch.randn_like(action))
        return tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(alpha={self.alpha.item():.4g}, "
            f"noise_scale={self.noise_scale.item():g}, "
            f"target_entropy={self.target_entropy.item():g}, action_key={self.action_key!r})"
        )


@torch.no_grad()
def sampled_entropy(
    policy: nn.Module,
    observation: Tensor,
    num_samples: int,
    num_components: int = 3,
    *,
    observation_key: NestedKey = "observation",
    action_key: NestedKey = "action",
) -> Tensor:
    """DACER's entropy estimate of a stochastic ``policy`` at each state, ``[B]``.

    ``num_samples`` actions of each of the ``B`` states in ``observation`` (one batched
    call under ``ExplorationType.RANDOM``), then
    :func:`~torchrl_dual.modules.exploration.gmm_entropy.mixture_entropy` of each
    state's samples (DACER regulates with the mean).

    Args:
        policy (nn.Module): a TensorDict module reading ``observation_key`` and writing
            ``action_key`` (e.g. the diffusion actor followed by
            :class:`EntropyRegulatedNoise` and the action box).
        observation (Tensor): ``[B, S]`` states.
        num_samples (int): ``K`` actions per state, ``>= num_components``.
        num_components (int): ``C`` of the mixture. Defaults to 3.

    Keyword Args:
        observation_key (NestedKey): what the policy reads. Defaults to ``"observation"``.
        action_key (NestedKey): what it writes. Defaults to ``"action"``.

    Examples:
        >>> import math, torch
        >>> from tensordict import TensorDict
        >>> noise = EntropyRegulatedNoise(target_entropy=-1.8, noise_scale=0.5, init_alpha=1.0)
        >>> def policy(td):  # action = s, plus the noise
        ...     return noise(td.set("action", td["observation"].clone()))
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> h = sampled_entropy(policy, torch.zeros(4, 2), num_samples=2000, num_components=1)
        >>> exact = 1 + math.log(2 * math.pi) + 2 * math.log(0.5)  # N(s, 0.25 I) in 2-D
        >>> bool((h - exact).abs().max() < 0.1)
        True
    """
    batch, repeats = observation.shape[0], int(num_samples)
    states = observation.repeat_interleave(repeats, dim=0)  # [B K, S], state-major
    td = TensorDict({observation_key: states}, batch_size=[batch * repeats])
    with set_exploration_type(ExplorationType.RANDOM):
        actions = policy(td)[action_key]
    return mixture_entropy(actions.reshape(batch, repeats, -1), num_components)
