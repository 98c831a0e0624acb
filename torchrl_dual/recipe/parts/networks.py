"""The networks several algorithms build from their typed settings (Algorithm 1 line 1).

The trajectory diffusion planner (DUAL, EDIS, the Diffuser), an untrained copy of it
(DUAL's actor and transition model) and the acting policy of a Laplace ensemble (DUAL and
the ``*_la`` baselines). DUAL's own builders are in :mod:`torchrl_dual.recipe.algos.dual`.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch
from tensordict.nn import TensorDictSequential
from torchrl.data.tensor_specs import TensorSpec
from torchrl.data.utils import DEVICE_TYPING

from torchrl_dual import TransitionModel, make_dual_policy
from torchrl_dual.data import OfflineDataset
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import LastLayerActor
from torchrl_dual.recipe.settings.dual import EnsembleSettings, PlannerSettings


def make_planner(
    planner: PlannerSettings, data: OfflineDataset, device: DEVICE_TYPING = "cpu"
) -> TrajectoryDiffusion:
    """The N-step diffusion planner ``g_θ'`` (Eq. 3) of ``planner``.

    Its normalizer is fitted on ``D_offline``.
    """
    layout = TrajectoryLayout(data.obs_dim, data.action_dim, planner.horizon)
    model = TrajectoryDiffusion(
        layout,
        num_steps=planner.num_steps,
        schedule=planner.schedule,
        hidden=planner.hidden,
        depth=planner.depth,
    )
    model.normalizer.fit(data.transitions["observation"], data.transitions["action"])
    return model.to(device)


def student_like(teacher: TrajectoryDiffusion, num_steps: int = 1) -> TrajectoryDiffusion:
    """An untrained copy of the teacher sampled with ``num_steps`` steps, to load the student into.

    The copy has the teacher's architecture, initial weights and fitted normalizer.
    """
    student = copy.deepcopy(teacher)
    student.num_steps = num_steps
    return student


def make_policy(
    laplace: EnsembleSettings,
    actor: LastLayerActor,
    action_spec: TensorSpec,
    *,
    transition: TransitionModel | None = None,
    shift_weight: float = 0.0,
    action_projection: Callable[[torch.Tensor], torch.Tensor] | None = None,
    device: DEVICE_TYPING = "cpu",
) -> TensorDictSequential:
    """The acting policy of a ``laplace`` section: Eq. 9's ensemble, then Eq. 10's noise.

    The ensemble of Eq. (9) over the Laplace posterior (or, with DUAL's
    ``laplace.uq=latent``, over planner latents), which also answers the transition
    model's ``ŝ_t`` when there is one, then the shift-aware noise (Eq. 10, ``λ =
    shift_weight``) and the env kit's ``action_projection``. DUAL's, and the ``*_la``
    baselines' (no transition model, ``λ = 0``).
    """
    return make_dual_policy(
        actor,
        action_spec,
        transition_model=transition,
        num_samples=laplace.num_samples,
        prior_precision=laplace.prior_precision,
        posterior_temperature=laplace.posterior_temperature,
        shift_weight=shift_weight,
        uncertainty=getattr(laplace, "uq", "laplace"),
        action_projection=action_projection,
        device=device,
    )
