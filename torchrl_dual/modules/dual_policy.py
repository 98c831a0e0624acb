"""DUAL's acting policy, assembled in one place (Eq. 9 + Eq. 10, Algorithm 1 l. 11)."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict.nn import TensorDictSequential
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.data.tensor_specs import BoundedContinuous, Composite, TensorSpec

from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.modules.exploration.shift_aware_noise import (
    DEFAULT_SHIFT_WEIGHT,
    ShiftAwareNoise,
)
from torchrl_dual.modules.laplace.laplace_ensemble_actor import LaplaceEnsembleActor
from torchrl_dual.modules.laplace.latent_ensemble_actor import LatentEnsembleActor
from torchrl_dual.modules.planner.transition_model import TransitionModel

UNCERTAINTIES = ("laplace", "latent")
"""Where the ``M`` sub-policies of Eq. (9) come from: the last-layer Laplace posterior
(DUAL) or the planner's latent ``τ^N ~ N(0, I)`` (the "w τ^N sampling" ablation)."""


def make_dual_policy(
    actor: LastLayerActor,
    action_spec: TensorSpec,
    *,
    transition_model: TransitionModel | None = None,
    num_samples: int = 5,
    prior_precision: str | float = "evidence",
    posterior_temperature: str | float = 1.0,
    shift_weight: float = DEFAULT_SHIFT_WEIGHT,
    uncertainty: str = "laplace",
    action_projection: Callable[[Tensor], Tensor] | None = None,
    return_log_prob: bool = False,
    action_key: NestedKey = "action",
    device: torch.device | str | None = None,
) -> TensorDictSequential:
    """DUAL's online policy: Laplace ensemble (Eq. 9) then shift-aware noise (Eq. 10).

    Returns ``TensorDictSequential(ensemble, noise)``: ``policy[0]`` is the
    :class:`~torchrl_dual.modules.LaplaceEnsembleActor` (fit its posterior with
    ``policy[0].fit_laplace(...)`` before acting), which also answers the
    ``transition_model``'s query ``ŝ_t`` in its trunk pass; ``policy[1]`` is the
    :class:`~torchrl_dual.modules.ShiftAwareNoise` that draws the executed action with
    variance ``σ²(s_t) + λ d_t`` and projects it on ``action_spec``. The env must carry
    the previous step: append :class:`~torchrl_dual.transforms.PreviousTransition`.

    Args:
        actor (LastLayerActor): DUAL's :class:`~torchrl_dual.modules.PlannerActor`, or any
            last-layer actor (``LinearHeadActor`` makes "IQL + LA").
        action_spec (TensorSpec): the env's action spec; a bounded box also clamps the
            ensemble's mean action.

    Keyword Args:
        transition_model (TransitionModel, optional): the source of ``ŝ_t``; required
            when ``shift_weight > 0``. ``TransitionModel.frozen_copy(student)`` keeps the
            distilled offline weights, ``TransitionModel(actor.model, frozen=False)``
            shares the actor's.
        num_samples (int): ``M`` posterior samples. Defaults to ``5``.
        prior_precision (str or float): ``"evidence"`` or a fixed value.
        posterior_temperature (str or float): ``T`` of the posterior covariance, or
            ``"data"`` (:class:`~torchrl_dual.modules.LastLayerLaplace`'s ``temperature``).
            Defaults to ``1.0``.
        shift_weight (float): ``λ`` of Eq. 10. Defaults to ``0.5``.
        uncertainty (str): ``"laplace"`` (default): ``policy[0]`` is the
            :class:`~torchrl_dual.modules.LaplaceEnsembleActor`; ``"latent"``: the
            :class:`~torchrl_dual.modules.laplace.LatentEnsembleActor`, whose ``M``
            sub-policies are ``M`` planner latents (no posterior to fit;
            ``prior_precision`` and ``posterior_temperature`` are unused).
        action_projection (callable, optional): applied to the executed action (e.g. the
            one-hot argmax of a discrete env).
        return_log_prob (bool): also write ``action_log_prob``. Defaults to ``False``.
        action_key (NestedKey): the executed action's key, and its entry in a Composite
            ``action_spec``. Defaults to ``"action"``.
        device (torch.device, optional): where the policy lives.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Bounded
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> from torchrl_dual.modules import PlannerActor, TransitionModel
        >>> student = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = student.normalizer.fit(torch.randn(64, 3), torch.rand(64, 2) * 2 - 1)
        >>> policy = make_dual_policy(
        ...     PlannerActor(student), Bounded(-1.0, 1.0, shape=(2,)),
        ...     transition_model=TransitionModel.frozen_copy(student))
        >>> _ = policy[0].fit_laplace([TensorDict(observation=torch.randn(64, 3), batch_size=[64])])
        >>> td = policy(TensorDict(
        ...     observation=torch.randn(4, 3), previous_observation=torch.randn(4, 3),
        ...     previous_action=torch.zeros(4, 2),
        ...     previous_valid=torch.ones(4, 1, dtype=torch.bool), batch_size=[4]))
        >>> td["action"].shape, td["shift_distance"].shape
        (torch.Size([4, 2]), torch.Size([4, 1]))
    """
    if transition_model is None and shift_weight > 0:
        raise ValueError(
            f"shift_weight={shift_weight} needs ŝ_t: pass transition_model="
            "TransitionModel.frozen_copy(student) (or TransitionModel(actor.model, "
            "frozen=False)), or set shift_weight=0."
        )
    spec = action_spec[action_key] if isinstance(action_spec, Composite) else action_spec
    low = high = None
    if isinstance(spec, BoundedContinuous):
        low, high = spec.space.low.to(device or "cpu"), spec.space.high.to(device or "cpu")
    if uncertainty not in UNCERTAINTIES:
        raise ValueError(f"Unknown uncertainty {uncertainty!r}; choose one of {UNCERTAINTIES}.")
    members = (
        {"prior_precision": prior_precision, "posterior_temperature": posterior_temperature}
        if uncertainty == "laplace"
        else {}
    )
    ensemble_class = LaplaceEnsembleActor if uncertainty == "laplace" else LatentEnsembleActor
    ensemble = ensemble_class(
        actor,
        num_samples=num_samples,
        action_low=low,
        action_high=high,
        sample_action=False,  # ShiftAwareNoise draws the executed action (Eq. 10)
        transition_model=transition_model,
        action_key=action_key,
        **members,
    )
    noise = ShiftAwareNoise(
        action_spec,
        shift_weight=shift_weight,
        action_projection=action_projection,
        return_log_prob=return_log_prob,
        action_key=action_key,
    )
    return TensorDictSequential(ensemble, noise).to(device or "cpu")
