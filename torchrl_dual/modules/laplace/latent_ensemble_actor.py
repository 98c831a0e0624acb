"""The latent-sampling ensemble, the paper's "Ours w τ^N sampling" ablation of Eq. (9)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey

from torchrl_dual._utils import is_deterministic, read_key
from torchrl_dual.modules._gaussian import gaussian_log_prob
from torchrl_dual.modules.actors.planner_actor import PlannerActor
from torchrl_dual.modules.laplace._action_bounds import ActionBounds
from torchrl_dual.modules.planner.transition_model import TransitionModel


class LatentEnsembleActor(ActionBounds, TensorDictModuleBase):
    """Ensemble policy over ``M`` planner latents instead of ``M`` posterior heads.

    The paper's ablation "Ours w τ^N sampling" (Sec. 5, ablation studies) replaces the
    Laplace posterior by the diffusion model's own randomness: sub-policy ``m`` is the
    planner actor's action for a latent ``τ^N_m ~ N(0, I)`` drawn anew at every call,
    through the actor's current (MAP) weights
    (:meth:`~torchrl_dual.modules.PlannerActor.sample_actions`). The ``M`` actions are
    aggregated as in Eq. (9):

    ``μ(s) = (1/M) Σ_m (τ_{a_0})_m``,  ``σ²(s) = (1/M) Σ_m [(μ(s) − (τ_{a_0})_m)² + σ̄²]``.

    It writes the keys of :class:`~torchrl_dual.modules.LaplaceEnsembleActor` (``loc``,
    ``scale``, ``epistemic_variance``, ``action``, ``action_log_prob`` and, with a
    transition model, ``expected_observation``), so the
    :class:`~torchrl_dual.modules.ShiftAwareNoise` of Eq. (10) follows it unchanged. No
    posterior is fitted; under ``DETERMINISTIC``/``MODE``/``MEAN`` it returns the actor's
    mean action ``μ(s)`` (its own latent, zero by default).

    Cost: the actor runs on ``M`` latents (``M`` batched trunk passes, times ``N`` steps
    for an ``N``-step actor) instead of one trunk pass and ``M`` heads.

    Args:
        actor (PlannerActor): the planner actor; its schedule must end in pure noise
            (``α_1 = 0``, the cosine schedule) so that ``τ^N ~ N(0, I)`` is the planner's
            own prior.

    Keyword Args:
        num_samples (int): ``M`` latents per call, ``>= 2`` (one latent has no spread).
            Defaults to ``5``.
        action_low, action_high (float or Tensor, optional): bounds of the action.
        sample_action (bool): draw ``action ∼ N(μ, σ²)`` under random exploration; set
            ``False`` when a :class:`~torchrl_dual.modules.ShiftAwareNoise` follows.
        transition_model (TransitionModel, optional): the source of ``ŝ_t`` (Eq. 10),
            written as ``expected_observation`` under random exploration.
        observation_key, loc_key, scale_key, epistemic_key, action_key, log_prob_key
            (NestedKey): input and output keys.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 3), torch.rand(64, 2) * 2 - 1)
        >>> policy = LatentEnsembleActor(PlannerActor(model), num_samples=5)
        >>> out = policy(TensorDict(observation=torch.randn(4, 3), batch_size=[4]))
        >>> out["action"].shape, bool((out["epistemic_variance"] > 0).all())
        (torch.Size([4, 2]), True)
    """

    def __init__(
        self,
        actor: PlannerActor,
        *,
        num_samples: int = 5,
        action_low: float | torch.Tensor | None = None,
        action_high: float | torch.Tensor | None = None,
        sample_action: bool = True,
        transition_model: TransitionModel | None = None,
        observation_key: NestedKey = "observation",
        loc_key: NestedKey = "loc",
        scale_key: NestedKey = "scale",
        epistemic_key: NestedKey = "epistemic_variance",
        action_key: NestedKey = "action",
        log_prob_key: NestedKey = "action_log_prob",
    ) -> None:
        super().__init__()
        if not isinstance(actor, PlannerActor):
            raise TypeError(
                "LatentEnsembleActor samples the planner's latent: it needs a PlannerActor, "
                f"got {type(actor).__name__}."
            )
        if num_samples < 2:
            raise ValueError(
                f"num_samples (M) must be >= 2 for a spread over latents, got {num_samples}."
            )
        alpha_1, _ = actor.model.schedule(torch.ones(()))
        if float(alpha_1) > 1e-6:
            raise ValueError(
                "Latent sampling draws τ^N ~ N(0, I), the planner's prior only when its "
                f"schedule ends in pure noise (α_1 = 0); the {actor.model.schedule.kind!r} "
                f"schedule has α_1 = {float(alpha_1):.2e}: use the cosine schedule."
            )
        if transition_model is not None and not isinstance(transition_model, TransitionModel):
            raise TypeError(
                f"transition_model must be a TransitionModel, got {type(transition_model).__name__}."
            )
        self.actor = actor
        self.num_samples = num_samples
        self.sample_action = sample_action
        self._set_bounds(action_low, action_high)
        self.transition_model = transition_model
        self.in_keys = [observation_key]
        self.out_keys = [loc_key, scale_key, epistemic_key, action_key, log_prob_key]
        if transition_model is not None:
            self.in_keys = self.in_keys + transition_model.in_keys[1:]
            self.out_keys = self.out_keys + transition_model.out_keys

    def member_actions(self, observation: torch.Tensor) -> torch.Tensor:
        """Actions of the ``M`` latent sub-policies, ``[M, *B, A]`` (fresh latents)."""
        return self.actor.sample_actions(observation, self.num_samples)

    def _write_expected(self, tensordict: TensorDictBase, observation: torch.Tensor) -> None:
        transition = self.transition_model
        if transition is None:
            return
        previous_observation, previous_action, valid = transition.read_previous(
            tensordict, "LatentEnsembleActor"
        )
        predicted = transition.predict(previous_observation, previous_action.to(observation.dtype))
        transition.write_expected(tensordict, observation, predicted, valid)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Acts with the ``τ^N``-sampling ensemble (Eq. 9's aggregation); writes ``out_keys``.

        Args:
            tensordict (TensorDictBase): holds the observation ``[*B, obs_dim]`` (and the
                previous step with a transition model).

        Returns:
            ``tensordict`` with ``loc``, ``scale``, ``epistemic_variance``, ``action``
            (``[*B, A]`` each), ``action_log_prob`` ``[*B]`` when this module samples, and
            ``expected_observation`` with a transition model.
        """
        observation = read_key(tensordict, self.in_keys[0], "LatentEnsembleActor")
        loc_key, scale_key, epistemic_key, action_key, log_prob_key = self.out_keys[:5]
        deterministic = is_deterministic()
        if deterministic:  # the actor's mean action, no epistemic part
            loc = self.actor(observation)
            epistemic = torch.zeros_like(loc)
        else:
            self._write_expected(tensordict, observation)
            epistemic, loc = torch.var_mean(self.member_actions(observation), 0, correction=0)
        scale = (epistemic + self.actor.std**2).sqrt()
        tensordict.set(loc_key, loc)
        tensordict.set(scale_key, scale)
        tensordict.set(epistemic_key, epistemic)
        if not deterministic and not self.sample_action:  # ShiftAwareNoise samples next
            tensordict.set(action_key, self._clamp(loc))
            return tensordict
        noise = 0.0 if deterministic else scale * torch.randn_like(loc)
        action = self._clamp(loc + noise)
        tensordict.set(action_key, action)
        tensordict.set(log_prob_key, gaussian_log_prob(action, loc, scale))
        return tensordict
