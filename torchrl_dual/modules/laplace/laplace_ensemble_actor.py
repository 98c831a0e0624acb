"""The Laplace ensemble policy of DUAL (Eq. 9)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torchrl.modules import IndependentNormal

from torchrl_dual._utils import is_deterministic, read_key, write_key
from torchrl_dual._versioned_cache import VersionedCache
from torchrl_dual.modules._gaussian import gaussian_log_prob
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.modules.laplace._action_bounds import ActionBounds
from torchrl_dual.modules.laplace.last_layer_laplace import LastLayerLaplace
from torchrl_dual.modules.planner.transition_model import TransitionModel


class LaplaceEnsembleActor(ActionBounds, TensorDictModuleBase):
    """Ensemble policy over ``M`` last-layer posterior samples, Eq. (9).

    With ``θ_m ∼ N(θ*, Σ)`` from the last-layer Laplace posterior (Eq. 8) and
    ``(τ_{a_0})_m`` the action of sub-policy ``m``:

    ``μ(s) = (1/M) Σ_m (τ_{a_0})_m``,  ``σ²(s) = (1/M) Σ_m [(μ(s) − (τ_{a_0})_m)² + σ̄²]``.

    The trunk ``φ(s)`` runs once; the ``M`` sampled heads are applied as one batched
    contraction ``[*B, d] × [M, A, d] → [M, *B, A]``: no loop over members. An actor
    with a ``squash`` (e.g. a ``TanhNormal`` actor wrapped by
    :meth:`~torchrl_dual.modules.LinearHeadActor.from_actor`) squashes each member's
    read-out, ``(τ_{a_0})_m = squash(readout(θ_m))``, before the mean and the variance
    are taken; the posterior itself is over the pre-squash head. Posterior
    samples are kept as deviations ``θ_m − θ*`` and added to the actor's *current* head,
    so between two refits the ensemble stays centred on the policy being trained.

    Under ``ExplorationType.RANDOM`` (or unset) it samples ``action ∼ N(μ, σ²)``; under
    ``DETERMINISTIC``/``MODE``/``MEAN`` it returns the MAP mean action with no sampling.
    It writes ``loc`` (μ), ``scale`` (σ), ``epistemic_variance`` (the first term of
    σ², zero in deterministic mode), ``action``, ``action_log_prob`` (unless
    ``sample_action=False``) and, with a transition model, ``expected_observation``
    (``s_t`` itself in deterministic mode: no shift is measured there): its ``out_keys``,
    in every mode.

    Args:
        actor (LastLayerActor): e.g. :class:`~torchrl_dual.modules.PlannerActor` or
            :class:`~torchrl_dual.modules.LinearHeadActor` (which makes "IQL + LA").

    Keyword Args:
        num_samples (int): ``M``. Defaults to ``5`` (paper, Appendix A). ``0`` turns the
            epistemic part off (the "no UQ" ablation): the policy acts with the MAP mean
            and ``σ̄`` only, ``epistemic_variance`` is zero and no posterior is needed.
        prior_precision (str or float): ``"evidence"`` or a fixed value, passed to
            :class:`~torchrl_dual.modules.LastLayerLaplace`.
        posterior_temperature (str or float): its ``temperature``: ``T`` scales the
            posterior covariance (``1.0``, the default: the summed-loss posterior);
            ``"data"`` is the Laplace of Eq. 7's mean loss, about ``N`` times wider.
        action_low, action_high (float or Tensor, optional): bounds the sampled action
            is clamped to.
        resample_each_call (bool): draw new ``θ_m`` at every call. By default the ``M``
            sub-policies are drawn at each :meth:`fit_laplace` and kept ("maintained",
            Section 3.3) until the next refit or :meth:`resample`, which also spares the
            action path the draw.
        sample_action (bool): draw ``action ∼ N(μ, σ²)`` under random exploration.
            Set ``False`` when a :class:`~torchrl_dual.modules.ShiftAwareNoise` follows: it
            draws the executed action itself (Eq. 10), so this module then writes
            ``action = μ`` and no ``action_log_prob``.
        transition_model (TransitionModel, optional): DUAL's transition model
            ``p(s'|s, a; θ)`` (Algorithm 1 l. 11). Under random exploration the ensemble
            then also reads the previous step (``previous_observation``,
            ``previous_action``, ``previous_valid``, written by the
            :class:`~torchrl_dual.transforms.PreviousTransition` env transform) and writes
            ``expected_observation`` ``ŝ_t`` (``s_t`` itself where no previous step
            exists), which :class:`~torchrl_dual.modules.ShiftAwareNoise` turns into
            ``d_t``. With a :class:`~torchrl_dual.modules.PlannerActor` both queries run as
            one batched trunk pass. Registered as a submodule (a frozen transition model's
            weights are saved with the ensemble; shared ones are saved by the actor).
        observation_key, loc_key, scale_key, epistemic_key, action_key, log_prob_key
            (NestedKey): input and output keys (the transition model's keys are its own).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP
        >>> from torchrl_dual.modules import LinearHeadActor
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
        >>> policy = LaplaceEnsembleActor(actor, num_samples=5)
        >>> data = TensorDict({"observation": torch.randn(64, 3)}, [64])
        >>> _ = policy.fit_laplace([data])
        >>> out = policy(TensorDict({"observation": torch.randn(4, 3)}, [4]))
        >>> out["action"].shape, out["epistemic_variance"].shape
        (torch.Size([4, 2]), torch.Size([4, 2]))
    """

    def __init__(
        self,
        actor: LastLayerActor,
        *,
        num_samples: int = 5,
        prior_precision: str | float = "evidence",
        posterior_temperature: str | float = 1.0,
        action_low: float | torch.Tensor | None = None,
        action_high: float | torch.Tensor | None = None,
        resample_each_call: bool = False,
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
        if num_samples < 0:
            raise ValueError(
                f"num_samples (M) must be >= 0 (0: no epistemic UQ), got {num_samples}."
            )
        if not isinstance(actor, LastLayerActor):
            raise TypeError(
                "LaplaceEnsembleActor needs a LastLayerActor (PlannerActor, LinearHeadActor, "
                f"DDPMLastStepActor), got {type(actor).__name__}; wrap a TorchRL actor with "
                "LinearHeadActor.from_actor(...)."
            )
        if transition_model is not None and not isinstance(transition_model, TransitionModel):
            raise TypeError(
                f"transition_model must be a TransitionModel, got {type(transition_model).__name__}."
            )
        if (
            transition_model is not None
            and transition_model.frozen
            and transition_model.model is getattr(actor, "model", None)
        ):
            raise ValueError(
                "transition_model=TransitionModel(actor.model) freezes the actor's own planner "
                "(frozen=True is the default), which would stop its fine-tuning. Share the "
                "weights with TransitionModel(actor.model, frozen=False), or keep a frozen "
                "copy with TransitionModel.frozen_copy(actor.model)."
            )
        self.actor = actor
        in_features = actor.head.in_features
        self.laplace = LastLayerLaplace(
            in_features,
            actor.action_dim,
            prior_precision=prior_precision,
            temperature=posterior_temperature,
            per_output_jacobian=actor.noise_after_squash,
        )
        self.num_samples = num_samples
        self.resample_each_call = resample_each_call
        self.sample_action = sample_action
        self.register_buffer(
            "weight_deviation", torch.zeros(num_samples, actor.action_dim, in_features)
        )
        self.register_buffer("bias_deviation", torch.zeros(num_samples, actor.action_dim))
        self._set_bounds(action_low, action_high)
        self.transition_model = transition_model
        # the sources of the stacked heads: the actor's head and this module's deviations
        self._member_head_cache = VersionedCache((actor.head, self), self._member_heads)
        self._aleatoric_cache = VersionedCache((actor,), self._actor_variance)  # σ̄²
        self.in_keys = [observation_key]
        self.out_keys = [loc_key, scale_key, epistemic_key, action_key]
        if sample_action:  # else the noise module that follows samples (and scores) it
            self.out_keys.append(log_prob_key)
        if transition_model is not None:
            self.in_keys = self.in_keys + transition_model.in_keys[1:]
            self.out_keys = self.out_keys + transition_model.out_keys

    # ------------------------------------------------------------------ Eq. (8)
    @torch.no_grad()
    def fit_laplace(
        self,
        batches: Iterable[TensorDictBase],
        *,
        weight_fn: Callable[[TensorDictBase], torch.Tensor] | None = None,
    ) -> LastLayerLaplace:
        """(Re)fits the last-layer posterior on ``batches`` (Algorithm 1, lines 9 and 17).

        Streams the trunk features of every batch into the Gram matrix ``G`` with the
        actor-loss weights ``w_i`` (``weight_fn(batch)``, e.g.
        ``WeightedMAPActorLoss.advantage_weights``; uniform when omitted), then fits
        ``P = G / σ_head² + λI`` around the current head, with
        ``σ_head = σ̄ / |readout_scale|`` (in the pre-squash space of a squashed actor).
        An actor with ``noise_after_squash`` has its Gaussian on the squashed mean: each
        sample's Gram term is weighted per action dimension by the squared Jacobian of the
        mean in the head output (:meth:`~LastLayerActor.mean_jacobian`, a generalised
        Gauss-Newton Hessian) and ``σ_head = σ̄``.
        Feed the whole data set: the posterior of Eq. (8) is over the summed loss.
        The ``M`` sub-policies are drawn anew (:meth:`resample`).

        Args:
            batches (iterable of TensorDictBase): the data to fit on, e.g.
                ``[offline_data]`` or the replay buffer's offline and online storages;
                each holds states ``[*B, obs_dim]`` under the observation key (only the
                states are read, plus what ``weight_fn`` reads).

        Keyword Args:
            weight_fn (callable, optional): ``batch -> w [*B]``, the non-negative Eq. 7
                weight of each sample (e.g. ``WeightedMAPActorLoss.advantage_weights``);
                normalised to mean 1 over all batches. Uniform when ``None``.

        Returns:
            LastLayerLaplace: the fitted posterior (:attr:`laplace`), with its MAP head
            ``θ*``, prior precision ``λ`` and the precisions of Eq. 8.

        Raises:
            ValueError: ``batches`` holds no state; a weight is negative, NaN or inf, or
                not shaped like the batch; the features or the MAP head hold a NaN or
                inf.
            KeyError: a batch lacks the observation key.

        Examples:
            >>> import torch
            >>> from tensordict import TensorDict
            >>> from torchrl.modules import MLP
            >>> from torchrl_dual.modules import LinearHeadActor
            >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
            >>> policy = LaplaceEnsembleActor(actor, num_samples=4)
            >>> data = TensorDict(observation=torch.randn(128, 3), batch_size=[128])
            >>> laplace = policy.fit_laplace([data[:64], data[64:]],
            ...                              weight_fn=lambda batch: torch.ones(batch.shape))
            >>> laplace.is_fitted, tuple(policy.member_actions(torch.randn(5, 3)).shape)
            (True, (4, 5, 2))
        """
        actor = self.actor
        self.laplace.reset()
        states = 0
        for batch in batches:
            observation = read_key(batch, self.in_keys[0], "LaplaceEnsembleActor.fit_laplace")
            states += observation.numel() // max(observation.shape[-1], 1)
            features, context = actor.encode(observation)
            weights = None if weight_fn is None else weight_fn(batch)
            jacobian = None
            if actor.noise_after_squash:
                jacobian = actor.mean_jacobian(actor.head_output(features), context)
            self.laplace.accumulate(features, weights, jacobian)
        if states == 0:
            raise ValueError(
                "fit_laplace got no data: pass TensorDict batches of states under "
                f"{self.in_keys[0]!r}, e.g. [offline_data] (Eq. 8 fits on the whole data set)."
            )
        rows = actor.head_rows
        if actor.noise_after_squash:
            noise_variance = actor.std**2
        else:
            noise_variance = (actor.std / actor.readout_scale().abs()) ** 2
        self.laplace.fit(actor.head.weight[rows], actor.head.bias[rows], noise_variance.detach())
        self.resample()
        return self.laplace

    @torch.no_grad()
    def resample(self, generator: torch.Generator | None = None) -> None:
        """Draws the ``M`` sub-policies ``θ_m ∼ N(θ*, Σ)`` anew, stored as deviations ``θ_m − θ*``."""
        weight, bias = self.laplace.weight_samples_split(self.num_samples, generator=generator)
        theta = self.laplace.theta_map.to(weight.dtype)
        self.weight_deviation.copy_(weight - theta[..., :-1])
        self.bias_deviation.copy_(bias - theta[..., -1])

    # ------------------------------------------------------------------ Eq. (9)
    def member_actions(self, observation: torch.Tensor) -> torch.Tensor:
        """Actions of the ``M`` sub-policies, ``[M, *B, A]``, in one batched pass."""
        features, context = self.actor.encode(observation)
        return self._members(features, context)

    def _member_heads(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``M`` heads ``θ* + (θ_m − θ*)`` stacked as one ``[M·A, d]`` linear map."""
        map_weight, map_bias = self.actor.head_parameters()
        weight = (map_weight + self.weight_deviation).flatten(0, 1)
        return weight, (map_bias + self.bias_deviation).flatten()

    def _members(self, features: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        if self.resample_each_call:
            self.resample()
        # all M heads as one linear map [*B, d] -> [*B, M·A] -> [M, *B, A]; without
        # autograd the stacked heads are reused until the head or the draws change
        if torch.is_grad_enabled():
            weight, bias = self._member_heads()
        else:
            weight, bias = self._member_head_cache.get()
        heads = torch.nn.functional.linear(features, weight, bias)
        heads = heads.unflatten(-1, (self.num_samples, -1)).movedim(-2, 0)
        return self.actor.act(heads, context)  # read-out, then the actor's squash if any

    def _encode(self, tensordict: TensorDictBase, observation: torch.Tensor):
        """Trunk pass; with a transition model it also writes ``ŝ_t`` (same pass)."""
        transition = self.transition_model
        if transition is None:
            return self.actor.encode(observation)
        previous_observation, previous_action, valid = transition.read_previous(
            tensordict, "LaplaceEnsembleActor"
        )
        features, context, predicted = self.actor.encode_with_transition(
            observation, transition, previous_observation, previous_action
        )
        transition.write_expected(tensordict, observation, predicted, valid)
        return features, context

    def get_dist(self, tensordict: TensorDictBase) -> IndependentNormal:
        """Eq. 9's policy as a TorchRL distribution, ``IndependentNormal(μ(s), σ(s))``.

        It has the ensemble's mean and std (under ``DETERMINISTIC``: the MAP mean
        and ``σ̄``), as ``ProbabilisticActor.get_dist``; ``tensordict`` is not
        written to.

        Examples:
            >>> import torch
            >>> from tensordict import TensorDict
            >>> from torchrl.modules import MLP
            >>> from torchrl_dual.modules import LinearHeadActor
            >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
            >>> policy = LaplaceEnsembleActor(actor, num_samples=5)
            >>> _ = policy.fit_laplace([TensorDict(observation=torch.randn(64, 3), batch_size=[64])])
            >>> policy.get_dist(TensorDict(observation=torch.randn(4, 3), batch_size=[4])).mean.shape
            torch.Size([4, 2])
        """
        out = self(tensordict.copy())
        return IndependentNormal(out.get(self.out_keys[0]), out.get(self.out_keys[1]))

    def _actor_variance(self) -> torch.Tensor:
        return self.actor.std**2

    def _aleatoric_variance(self) -> torch.Tensor:
        """``σ̄²``, the actor's (cached between its updates when no gradient is taken)."""
        if torch.is_grad_enabled():
            return self.actor.std**2
        return self._aleatoric_cache.get()

    def _write(
        self,
        tensordict: TensorDictBase,
        loc: torch.Tensor,
        scale: torch.Tensor,
        epistemic: torch.Tensor,
        action: torch.Tensor,
    ) -> None:
        """Writes ``loc``, ``scale``, ``epistemic_variance`` and ``action``."""
        loc_key, scale_key, epistemic_key, action_key = self.out_keys[:4]
        write_key(tensordict, loc_key, loc)
        write_key(tensordict, scale_key, scale)
        write_key(tensordict, epistemic_key, epistemic)
        write_key(tensordict, action_key, action)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Acts with Eq. 9's ensemble policy and writes its ``out_keys``.

        Under random exploration the ``M`` members give ``μ(s)`` and the epistemic variance,
        ``σ² = epistemic + σ̄²``, and ``action ∼ N(μ, σ²)`` (or ``action = μ`` with
        ``sample_action=False``); deterministic modes give the MAP mean and no epistemic part.

        Args:
            tensordict (TensorDictBase): holds the observation ``[*B, obs_dim]`` (and the
                previous step with a transition model).

        Returns:
            ``tensordict`` with ``loc``, ``scale``, ``epistemic_variance``, ``action``
            (``[*B, A]`` each), ``action_log_prob`` ``[*B]`` when this module samples, and
            ``expected_observation`` with a transition model.

        Raises:
            RuntimeError: the posterior is not fitted (``num_samples > 0``, random exploration).
        """
        observation = read_key(tensordict, self.in_keys[0], "LaplaceEnsembleActor")
        aleatoric = self._aleatoric_variance()
        if is_deterministic():
            if self.transition_model is not None:  # no exploration: ŝ_t = s_t, d_t = 0
                write_key(tensordict, self.transition_model.out_keys[0], observation)
            loc = self.actor(observation)
            epistemic = torch.zeros_like(loc)
            scale = aleatoric.expand_as(loc).sqrt()
            action = self._clamp(loc)
        else:
            if self.num_samples == 0:  # no epistemic UQ: the MAP mean, σ̄ only
                features, context = self._encode(tensordict, observation)
                loc = self.actor.act(self.actor.head_output(features), context)
                epistemic = torch.zeros_like(loc)
            elif not self.laplace.is_fitted:
                raise RuntimeError(
                    "LaplaceEnsembleActor samples from the last-layer posterior: call "
                    "fit_laplace(...) on the offline data first."
                )
            else:
                members = self._members(*self._encode(tensordict, observation))
                epistemic, loc = torch.var_mean(members, 0, correction=0)
            scale = (epistemic + aleatoric).sqrt()
            if not self.sample_action:  # the next module (ShiftAwareNoise) samples
                self._write(tensordict, loc, scale, epistemic, self._clamp(loc))
                return tensordict
            action = self._clamp(loc + scale * torch.randn_like(loc))
        self._write(tensordict, loc, scale, epistemic, action)
        if self.sample_action:  # out_keys[4]: the action's log-density
            write_key(tensordict, self.out_keys[4], gaussian_log_prob(action, loc, scale))
        return tensordict
