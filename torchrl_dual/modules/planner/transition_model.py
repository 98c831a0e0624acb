"""DUAL's transition model ``p(s' | s, a; θ)``: the one owner of ``ŝ_t`` (Alg. 1, l. 5 and 11)."""

from __future__ import annotations

import copy

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey

from torchrl_dual._utils import read_key, write_key
from torchrl_dual.diffusion.model import LATENTS, TrajectoryDiffusion
from torchrl_dual.modules.planner.planner_sampler import PlannerSampler

_PREVIOUS_FIX = "Append torchrl_dual.transforms.PreviousTransition() to the env."


class TransitionModel(TensorDictModuleBase):
    """The planner's transition model: ``ŝ_t`` from ``(s_{t-1}, a_{t-1})`` (Eq. 10's ``ŝ``).

    The planner is trained with ``a_0`` sometimes known (see
    :class:`~torchrl_dual.objectives.DiffusionPlannerLoss`), so sampling it with both
    ``s_0`` and ``a_0`` given and reading ``τ_{s_1}`` is a transition model. DUAL's
    shift signal (Eq. 10) compares its prediction for the current state with the state
    the env actually returned: ``d_t = ‖ŝ_t − s_t‖``.

    As a :class:`~tensordict.nn.TensorDictModuleBase` it reads the previous step carried
    by the :class:`~torchrl_dual.transforms.PreviousTransition` env transform and writes
    ``expected_observation`` ``ŝ_t`` (``s_t`` itself right after a reset, so ``d_t = 0``),
    which :class:`~torchrl_dual.modules.ShiftAwareNoise` turns into ``d_t``. Give it to
    :class:`~torchrl_dual.modules.LaplaceEnsembleActor` (``transition_model=``) and the
    ensemble answers this query in the same batched pass as the policy's;
    :meth:`predict` is the tensor-level call.

    **Whose weights.** With ``frozen=True`` (default) this module owns ``model``: it is
    registered (saved in :meth:`state_dict`, moved by ``.to()``) and frozen
    (``requires_grad=False``), typically a copy of the distilled student that the actor's
    fine-tuning leaves alone (:meth:`frozen_copy`). With ``frozen=False`` the weights
    are shared with the module that trains them, e.g. ``PlannerActor.model`` (Algorithm 1
    writes one ``θ`` for ``π_θ`` and ``p(s'|s, a; θ)``): they are then held by reference
    only, so the owner saves and moves them and no weight is stored twice.

    Args:
        model (TrajectoryDiffusion): the planner, usually the one-step student of
            :func:`~torchrl_dual.objectives.progressive_distillation`.

    Keyword Args:
        frozen (bool): own and freeze ``model`` (see above). Defaults to ``True``.
        num_steps (int, optional): sampling steps. Defaults to ``model.num_steps``.
        latent (str): ``"zero"`` (default): the prediction is the DDIM image of the zero
            latent in every exploration mode, so ``d_t`` measures the shift and not the
            model's own sampling noise; ``"sample"`` draws the latent under random
            exploration.
        observation_key, previous_observation_key, previous_action_key,
            previous_valid_key, out_key (NestedKey): the input keys ``s_t``,
            ``s_{t-1}``, ``a_{t-1}``, the flag of a valid previous step, and the output
            key ``ŝ_t``. Defaults to ``"observation"``, ``"previous_observation"``,
            ``"previous_action"``, ``"previous_valid"``, ``"expected_observation"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 3), torch.randn(64, 2))
        >>> transition = TransitionModel.frozen_copy(model)
        >>> td = TensorDict(
        ...     observation=torch.randn(5, 3), previous_observation=torch.randn(5, 3),
        ...     previous_action=torch.randn(5, 2),
        ...     previous_valid=torch.tensor([[True]] * 4 + [[False]]), batch_size=[5])
        >>> out = transition(td)["expected_observation"]
        >>> out.shape, bool((out[4] == td["observation"][4]).all())  # reset: ŝ_t = s_t
        (torch.Size([5, 3]), True)
        >>> transition.predict(torch.randn(5, 3), torch.randn(5, 2)).shape
        torch.Size([5, 3])
    """

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        frozen: bool = True,
        num_steps: int | None = None,
        latent: str = "zero",
        observation_key: NestedKey = "observation",
        previous_observation_key: NestedKey = "previous_observation",
        previous_action_key: NestedKey = "previous_action",
        previous_valid_key: NestedKey = "previous_valid",
        out_key: NestedKey = "expected_observation",
    ) -> None:
        super().__init__()
        if not isinstance(model, TrajectoryDiffusion):
            raise TypeError(
                f"TransitionModel needs a TrajectoryDiffusion planner, got {type(model).__name__}."
            )
        if latent not in LATENTS:
            raise ValueError(f"Unknown latent {latent!r}; choose one of {LATENTS}.")
        self.frozen = frozen
        if frozen:
            self.model = model.requires_grad_(False)
        else:  # shared: held by reference, owned (saved, moved) by the module that trains it
            self.__dict__["model"] = model
        self.__dict__["_sampler"] = PlannerSampler(model, num_steps=num_steps)
        self.latent = latent
        self.in_keys = [
            observation_key,
            previous_observation_key,
            previous_action_key,
            previous_valid_key,
        ]
        self.out_keys = [out_key]

    @classmethod
    def frozen_copy(cls, model: TrajectoryDiffusion, **kwargs) -> TransitionModel:
        """A transition model with its own frozen copy of ``model``'s weights."""
        return cls(copy.deepcopy(model), frozen=True, **kwargs)

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """``ŝ'`` for ``[*B, obs_dim]`` states and ``[*B, action_dim]`` actions, raw units."""
        return self._sampler.predict_next_observation(
            observation, action, deterministic=True if self.latent == "zero" else None
        )

    def read_previous(
        self, tensordict: TensorDictBase, reader: str = "TransitionModel"
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(s_{t-1}, a_{t-1}, valid)`` from ``tensordict``, with an error naming the fix."""
        _, observation_key, action_key, valid_key = self.in_keys
        return (
            read_key(tensordict, observation_key, reader, _PREVIOUS_FIX),
            read_key(tensordict, action_key, reader, _PREVIOUS_FIX),
            read_key(tensordict, valid_key, reader, _PREVIOUS_FIX),
        )

    def write_expected(
        self,
        tensordict: TensorDictBase,
        observation: torch.Tensor,
        predicted: torch.Tensor,
        valid: torch.Tensor,
    ) -> None:
        """Writes ``ŝ_t``: the prediction where a previous step exists, else ``s_t``."""
        if predicted.shape != observation.shape:
            raise ValueError(
                f"The transition model predicted shape {tuple(predicted.shape)} for "
                f"observations of shape {tuple(observation.shape)}; previous_observation "
                "must have the observation's shape."
            )
        write_key(tensordict, self.out_keys[0], torch.where(valid, predicted, observation))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Writes ``ŝ_t``, the prediction for the previous step (Eq. 10), as ``out_key``.

        Args:
            tensordict (TensorDictBase): holds ``s_t``, ``s_{t-1}``, ``a_{t-1}`` and the valid
                flag (from :class:`~torchrl_dual.transforms.PreviousTransition`).

        Returns:
            ``tensordict`` with ``ŝ_t`` ``[*B, obs_dim]`` (``s_t`` where no previous step exists).
        """
        observation = read_key(tensordict, self.in_keys[0], "TransitionModel")
        previous_observation, previous_action, valid = self.read_previous(tensordict)
        predicted = self.predict(previous_observation, previous_action.to(observation.dtype))
        self.write_expected(tensordict, observation, predicted, valid)
        return tensordict
