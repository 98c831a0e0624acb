"""Shift-aware exploration noise of DUAL (Eq. 10, Alg. 1 "Sample a_t ~ ...")."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.data.tensor_specs import BoundedContinuous, Composite, TensorSpec
from torchrl.envs.utils import ExplorationType, exploration_type

from torchrl_dual.modules._gaussian import gaussian_log_prob

__all__ = ["ShiftAwareNoise"]


class ShiftAwareNoise(TensorDictModuleBase):
    r"""Shift-aware exploration noise, DUAL Eq. 10.

    Placed after the ensemble actor (Eq. 9) in a
    :class:`~tensordict.nn.TensorDictSequential`, it draws the executed action from

    .. math::

        a_t \sim \mathcal{N}\big(\mu_\theta(s_t),\ \sigma_\theta^2(s_t) + \lambda\, d_t\big),
        \qquad d_t = \lVert \hat s_t - s_t \rVert_2 ,

    where ``ŝ_t = p(s' | s_{t-1}, a_{t-1}; θ)`` is the transition model's prediction for the
    current state from the previous state and the action actually executed there
    (Algorithm 1 l. 12; DESIGN "Exploration noise"). Alg. 1 writes the same sample as
    ``a_t ~ π̂(·|s_t) + λ N(0, d_t)``; this module follows Eq. 10 and adds ``λ d_t`` to
    the variance.

    ``ŝ_t`` comes from one of two places:

    * ``expected_observation`` in the input, written by
      :class:`~torchrl_dual.modules.LaplaceEnsembleActor` with ``predict_transition=True``,
      which answers the policy query for ``s_t`` and the transition query for
      ``(s_{t-1}, a_{t-1})`` in one trunk pass (the fast path, the paper's shared ``θ``);
    * otherwise ``transition_model(previous_observation, previous_action)``, a separate
      callable (e.g. a frozen copy of the offline transition model), where
      ``previous_valid``; ``ŝ_t = s_t`` (``d_t = 0``) right after a reset.

    The ``previous_*`` entries are carried by the
    :class:`~torchrl_dual.transforms.PreviousTransition` env transform.

    Steps of :meth:`forward`:

    1. Under ``ExplorationType.RANDOM`` (or unset): compute and write ``shift_distance``
       ``d_t`` (``[*B, 1]``); sample ``a = loc + sqrt(scale² + λ d) · ε`` (Eq. 10); project it
       onto the action spec (if any); write ``action``, the total std
       ``exploration_scale`` and, with ``return_log_prob=True``, ``action_log_prob``
       (Normal log-density of the executed, projected action summed over the action
       dim). ``scale`` is left as the Eq. 9 ensemble std.
    2. Under DETERMINISTIC / MODE / MEAN: ``action = loc`` (projected); nothing else.

    Because the noise is added on the policy side (like
    :class:`~torchrl.modules.AdditiveGaussianModule`), collectors and replay buffers
    store the executed action and the ``d_t`` it was drawn with; an inverse transform
    would store the noiseless action.

    ===========================  ============  ==============================================
    key (default)                shape         meaning
    ===========================  ============  ==============================================
    ``observation``              ``[*B, S]``   s_t
    ``loc``                      ``[*B, A]``   μ_θ(s_t), ensemble mean (Eq. 9)
    ``scale``                    ``[*B, A]``   σ_θ(s_t), ensemble std (Eq. 9), not modified
    ``expected_observation``     ``[*B, S]``   ŝ_t (optional input, see above)
    ``previous_observation``     ``[*B, S]``   s_{t-1} (used with ``transition_model``)
    ``previous_action``          ``[*B, A]``   a_{t-1} (used with ``transition_model``)
    ``previous_valid``           ``[*B, 1]``   False right after a reset
    ``shift_distance``           ``[*B, 1]``   d_t (output, RANDOM only)
    ``action``                   ``[*B, A]``   executed a_t (output)
    ``exploration_scale``        ``[*B, A]``   sqrt(σ² + λ d) (output, RANDOM only)
    ``action_log_prob``          ``[*B]``      log N(a_t; μ, σ² + λ d) (output, RANDOM and
                                               ``return_log_prob=True`` only)
    ===========================  ============  ==============================================

    Args:
        transition_model: optional callable ``(observation [*B, S], action [*B, A]) ->
            [*B, S]``, e.g. :meth:`TransitionModel.predict
            <torchrl_dual.modules.TransitionModel.predict>`; used when the input has no
            ``expected_observation``. An ``nn.Module`` is registered as a submodule.
        spec: action spec (or a Composite holding ``action_key``) used to project the
            action; ``None`` to skip projection or to set it later via :attr:`spec`.
        shift_weight: λ of Eq. 10 (a buffer, so it is checkpointed). Defaults to ``0.5``.
            With ``λ = 0`` and no source of ``ŝ_t`` the shift term is skipped.

    Keyword Args:
        observation_key, loc_key, scale_key, expected_observation_key,
        previous_observation_key, previous_action_key, previous_valid_key, shift_key,
        action_key, exploration_scale_key, log_prob_key (NestedKey): the keys of the
            table above.
        action_projection (callable, optional): applied to the action after the spec
            projection, before it is stored; e.g. the argmax one-hot map of a discrete
            env, so the stored action is the executed one.
        return_log_prob (bool): also write ``action_log_prob`` (as TorchRL's
            ``ProbabilisticActor(return_log_prob=True)``). Defaults to ``False``: the
            off-policy losses of the recipe do not read it, and the action path is hot.
        device (torch.device, optional): device of the ``shift_weight`` buffer.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Bounded
        >>> from torchrl_dual.modules.shift_aware import ShiftAwareNoise
        >>> noise = ShiftAwareNoise(lambda s, a: s + a, Bounded(-1.0, 1.0, shape=(2,)))
        >>> td = TensorDict(
        ...     observation=torch.ones(4, 2), loc=torch.zeros(4, 2),
        ...     scale=torch.full((4, 2), 0.1), previous_observation=torch.zeros(4, 2),
        ...     previous_action=torch.zeros(4, 2),
        ...     previous_valid=torch.ones(4, 1, dtype=torch.bool), batch_size=[4],
        ... )
        >>> td = noise(td)  # ŝ_t = 0 + 0, s_t = (1, 1): d_t = sqrt(2)
        >>> td["shift_distance"][0]
        tensor([1.4142])
        >>> td["exploration_scale"][0]  # sqrt(0.1**2 + 0.5 * sqrt(2))
        tensor([0.8468, 0.8468])
        >>> td["action"].shape
        torch.Size([4, 2])
    """

    _MISSING_KEY_ERR = (
        "ShiftAwareNoise expected the key {key!r} in the input tensordict ({what}), but it "
        "is missing. {fix}"
    )
    _SHAPE_ERR = (
        "ShiftAwareNoise: {key!r} has {what} {got}, expected {expected} ({why}). Fix: {fix}"
    )
    _PREVIOUS_FIX = "Append torchrl_dual.transforms.PreviousTransition() to the env."
    # Lower bound on the Eq. 10 variance so that σ = 0 and d = 0 stay finite.
    _MIN_VARIANCE = 1e-12

    def __init__(
        self,
        transition_model: Callable[[Tensor, Tensor], Tensor] | None = None,
        spec: TensorSpec | None = None,
        shift_weight: float = 0.5,
        *,
        observation_key: NestedKey = "observation",
        loc_key: NestedKey = "loc",
        scale_key: NestedKey = "scale",
        expected_observation_key: NestedKey = "expected_observation",
        previous_observation_key: NestedKey = "previous_observation",
        previous_action_key: NestedKey = "previous_action",
        previous_valid_key: NestedKey = "previous_valid",
        shift_key: NestedKey = "shift_distance",
        action_key: NestedKey = "action",
        exploration_scale_key: NestedKey = "exploration_scale",
        log_prob_key: NestedKey = "action_log_prob",
        action_projection: Callable[[Tensor], Tensor] | None = None,
        return_log_prob: bool = False,
        device: torch.device | None = None,
    ):
        if transition_model is not None and not callable(transition_model):
            raise TypeError(
                "ShiftAwareNoise: transition_model must be a callable "
                "(observation, action) -> predicted next observation, got "
                f"{type(transition_model).__name__}."
            )
        if not float(shift_weight) >= 0:
            raise ValueError(
                f"ShiftAwareNoise: shift_weight (λ of Eq. 10) must be >= 0, got {shift_weight}."
            )
        self.observation_key = observation_key
        self.loc_key = loc_key
        self.scale_key = scale_key
        self.expected_observation_key = expected_observation_key
        self.previous_keys = (previous_observation_key, previous_action_key, previous_valid_key)
        self.shift_key = shift_key
        self.action_key = action_key
        self.exploration_scale_key = exploration_scale_key
        self.log_prob_key = log_prob_key
        self.in_keys = [observation_key, loc_key, scale_key, expected_observation_key]
        if transition_model is not None:
            self.in_keys += list(self.previous_keys)
        self.out_keys = [action_key, shift_key, exploration_scale_key]
        if return_log_prob:
            self.out_keys.append(log_prob_key)
        super().__init__()
        self.return_log_prob = return_log_prob
        self.transition_model = transition_model
        self.action_projection = action_projection
        self.register_buffer(
            "shift_weight", torch.tensor(float(shift_weight), dtype=torch.float32, device=device)
        )
        self.spec = spec

    @property
    def spec(self) -> Composite | None:
        """Action spec (a Composite holding ``action_key``), or ``None`` for no projection."""
        return self._spec

    @spec.setter
    def spec(self, value: TensorSpec | None) -> None:
        if value is not None and not isinstance(value, Composite):
            value = Composite({self.action_key: value}, shape=value.shape[:-1])
        if value is not None and self.action_key not in value.keys(True, True):
            raise KeyError(
                f"ShiftAwareNoise: the Composite spec has no entry {self.action_key!r} "
                f"(keys: {list(value.keys(True, True))}). Pass the action spec itself or "
                "set action_key= to the key it holds."
            )
        self._spec = value
        # A continuous box is projected by a clamp to its bounds (what Bounded.project
        # does, without its per-call membership test); other specs use project().
        self._box = None
        if value is not None:
            action_spec = value[self.action_key]
            if isinstance(action_spec, BoundedContinuous):
                self._box = (action_spec.space.low, action_spec.space.high)

    @staticmethod
    def _fix(kwarg: str) -> str:
        return f"Place ShiftAwareNoise after an actor that writes it, or pass {kwarg}=<your key>."

    def _get(self, tensordict: TensorDictBase, key: NestedKey, what: str, fix: str) -> Tensor:
        value = tensordict.get(key, None)
        if value is None:
            raise KeyError(self._MISSING_KEY_ERR.format(key=key, what=what, fix=fix))
        return value

    def _check(self, key, got, expected, why, fix, what="shape") -> None:
        if tuple(got) != tuple(expected):
            got, expected = tuple(got), tuple(expected)
            raise ValueError(
                self._SHAPE_ERR.format(
                    key=key, what=what, got=got, expected=expected, why=why, fix=fix
                )
            )

    def _project(self, action: Tensor) -> Tensor:
        if self._box is not None:
            low, high = self._box
            if low.device != action.device:
                self._box = low, high = low.to(action.device), high.to(action.device)
            action = torch.clamp(action, low, high)
        elif self._spec is not None:
            action = self._spec[self.action_key].project(action)
        if self.action_projection is not None:
            action = self.action_projection(action)
        return action

    def _expected_observation(
        self, tensordict: TensorDictBase, observation: Tensor
    ) -> Tensor | None:
        """``ŝ_t``: from the ensemble's shared pass, else from ``transition_model``."""
        expected = tensordict.get(self.expected_observation_key, None)
        if expected is None and self.transition_model is not None:
            previous_observation, previous_action, valid = (
                self._get(tensordict, key, "the previous step", self._PREVIOUS_FIX)
                for key in self.previous_keys
            )
            predicted = self.transition_model(previous_observation, previous_action)
            self._check(
                "transition_model output",
                predicted.shape,
                observation.shape,
                f"ŝ_t must have the shape of {self.observation_key!r}",
                "make transition_model(observation, action) return [*B, obs_dim]",
            )
            expected = torch.where(valid, predicted, observation)
        if expected is None and float(self.shift_weight) > 0:
            raise KeyError(
                self._MISSING_KEY_ERR.format(
                    key=self.expected_observation_key,
                    what="ŝ_t, the transition model's prediction of s_t",
                    fix="Use LaplaceEnsembleActor(..., predict_transition=True) before "
                    "ShiftAwareNoise, or pass ShiftAwareNoise(transition_model=...); either "
                    "way append PreviousTransition() to the env. Or set shift_weight=0.",
                )
            )
        if expected is not None:
            self._check(
                self.expected_observation_key,
                expected.shape,
                observation.shape,
                f"ŝ_t has the shape of {self.observation_key!r}",
                "predict one next observation per env",
            )
        return expected

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Writes d_t and samples a_t by Eq. 10 (RANDOM mode); a_t = μ otherwise."""
        loc = self._get(
            tensordict, self.loc_key, "μ(s), the ensemble mean of Eq. 9", self._fix("loc_key")
        )
        if loc.ndim < 1:
            raise ValueError(
                f"ShiftAwareNoise: {self.loc_key!r} must have a trailing action dim [*B, A], "
                "got a scalar. Fix: unsqueeze(-1) the actor output."
            )
        if exploration_type() not in (ExplorationType.RANDOM, None):
            tensordict.set(self.action_key, self._project(loc))
            return tensordict
        scale = self._get(
            tensordict, self.scale_key, "σ(s), the ensemble std of Eq. 9", self._fix("scale_key")
        )
        self._check(
            self.scale_key,
            scale.shape,
            loc.shape,
            f"per-dimension std matching {self.loc_key!r}",
            "write one std per action dim (expand a shared std to loc's shape)",
        )
        observation = self._get(
            tensordict, self.observation_key, "s_t", self._fix("observation_key")
        )
        self._check(
            self.observation_key,
            observation.shape[:-1],
            loc.shape[:-1],
            f"[*B, S] with the batch dims *B of {self.loc_key!r} {tuple(loc.shape)}",
            "give the observation a trailing feature dim and the same batch dims as loc",
            what="batch dims",
        )
        variance = scale.square()
        expected = self._expected_observation(tensordict, observation)
        if expected is not None:
            shift = torch.linalg.vector_norm(expected - observation, dim=-1, keepdim=True)
            if shift.dtype != loc.dtype:
                shift = shift.to(loc.dtype)
            tensordict.set(self.shift_key, shift)  # d_t
            variance = torch.addcmul(variance, shift, self.shift_weight)  # Eq. (10)
        std = variance.clamp_min(self._MIN_VARIANCE).sqrt()
        action = self._project(torch.addcmul(loc, std, torch.randn_like(loc)))
        tensordict.set(self.action_key, action)
        tensordict.set(self.exploration_scale_key, std)
        if self.return_log_prob:
            tensordict.set(self.log_prob_key, gaussian_log_prob(action, loc, std))
        return tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(shift_weight={self.shift_weight.item():g}, "
            f"in_keys={self.in_keys}, out_keys={self.out_keys}, "
            f"projected={self._spec is not None})"
        )
