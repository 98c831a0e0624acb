"""Shift-aware exploration noise of DUAL (Eq. 10, Alg. 1 "Sample a_t ~ ...")."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.data.tensor_specs import Composite, TensorSpec
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

    where ``ŝ_t`` was predicted at ``t-1`` from ``(s_{t-1}, a_{t-1})`` by the transition
    model (DESIGN "Exploration noise"). ``d_t`` is written into the env data by the
    env-side :class:`~torchrl_dual.transforms.ShiftDistance` transform. Alg. 1 writes the
    same sample as ``a_t ~ π̂(·|s_t) + λ N(0, d_t)``; this module follows Eq. 10 and adds
    ``λ d_t`` to the variance.

    Steps of :meth:`forward`:

    1. Under ``ExplorationType.RANDOM`` (or unset): read ``loc`` (μ), ``scale`` (σ) and
       ``shift_distance`` (d, 0 if absent, e.g. at the first step); sample
       ``a = loc + sqrt(scale² + λ d) · ε`` (Eq. 10); project it onto the action spec (if
       any); write ``action``, the total std ``exploration_scale`` and ``action_log_prob``
       (Normal log-density of the executed, projected action summed over the action dim).
       ``scale`` is left as the Eq. 9 ensemble std.
    2. Under DETERMINISTIC / MODE / MEAN: ``action = loc`` (projected), no noise, no
       ``exploration_scale`` or ``action_log_prob``.
    3. In all modes: ``predicted_observation = transition_model(observation, action)``
       with the *executed* action; :class:`ShiftDistance` compares it with ``s_{t+1}``.

    Because the noise is added on the policy side (like
    :class:`~torchrl.modules.AdditiveGaussianModule`), collectors and replay buffers
    store the executed action; an inverse transform would store the noiseless one.

    ===========================  ============  ==============================================
    key (default)                shape         meaning
    ===========================  ============  ==============================================
    ``observation``              ``[*B, S]``   s_t, input of the transition model
    ``loc``                      ``[*B, A]``   μ_θ(s_t), ensemble mean (Eq. 9)
    ``scale``                    ``[*B, A]``   σ_θ(s_t), ensemble std (Eq. 9), not modified
    ``shift_distance``           ``[*B, 1]``   d_t (optional; 0 when absent)
    ``action``                   ``[*B, A]``   executed a_t (output)
    ``exploration_scale``        ``[*B, A]``   sqrt(σ² + λ d) (output, RANDOM only)
    ``action_log_prob``          ``[*B]``      log N(a_t; μ, σ² + λ d) (output, RANDOM only)
    ``predicted_observation``    ``[*B, S]``   ŝ_{t+1} (output, all modes)
    ===========================  ============  ==============================================

    Args:
        transition_model: callable ``(observation [*B, S], action [*B, A]) -> [*B, S]``,
            e.g. the distilled planner's one-step prediction ŝ1. An ``nn.Module`` is
            registered as a submodule (its weights follow the policy's).
        spec: action spec (or a Composite holding ``action_key``) used to project the
            action; ``None`` to skip projection or to set it later via :attr:`spec`.
        shift_weight: λ of Eq. 10 (a buffer, so it is checkpointed). Defaults to ``0.5``.

    Keyword Args:
        observation_key (NestedKey): s_t. Defaults to ``"observation"``.
        loc_key (NestedKey): μ_θ(s_t). Defaults to ``"loc"``.
        scale_key (NestedKey): σ_θ(s_t). Defaults to ``"scale"``.
        shift_key (NestedKey): d_t. Defaults to ``"shift_distance"``.
        action_key (NestedKey): executed action. Defaults to ``"action"``.
        prediction_key (NestedKey): ŝ_{t+1}. Defaults to ``"predicted_observation"``.
        exploration_scale_key (NestedKey): total std. Defaults to ``"exploration_scale"``.
        log_prob_key (NestedKey): log-density. Defaults to ``"action_log_prob"``.
        action_projection (callable, optional): applied to the action after the spec
            projection, before it is stored and fed to the transition model; e.g. the
            argmax one-hot map of a discrete env, so the stored action is the executed one.
        device (torch.device, optional): device of the ``shift_weight`` buffer.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Bounded
        >>> from torchrl_dual.modules.shift_aware import ShiftAwareNoise
        >>> noise = ShiftAwareNoise(lambda s, a: s + a, Bounded(-1.0, 1.0, shape=(2,)))
        >>> td = TensorDict(
        ...     observation=torch.zeros(4, 2), loc=torch.zeros(4, 2),
        ...     scale=torch.full((4, 2), 0.1), shift_distance=torch.ones(4, 1),
        ...     batch_size=[4],
        ... )
        >>> td = noise(td)
        >>> td["exploration_scale"][0]  # sqrt(0.1**2 + 0.5 * 1)
        tensor([0.7141, 0.7141])
        >>> td["action_log_prob"].shape, td["predicted_observation"].shape
        (torch.Size([4]), torch.Size([4, 2]))
    """

    _MISSING_KEY_ERR = (
        "ShiftAwareNoise expected the key {key!r} in the input tensordict ({what}), but it "
        "is missing. Place ShiftAwareNoise after an actor that writes it, or pass "
        "{kwarg}=<your key>."
    )
    _SHAPE_ERR = (
        "ShiftAwareNoise: {key!r} has {what} {got}, expected {expected} ({why}). Fix: {fix}"
    )
    # Lower bound on the Eq. 10 variance so that σ = 0 and d = 0 stay finite.
    _MIN_VARIANCE = 1e-12

    def __init__(
        self,
        transition_model: Callable[[Tensor, Tensor], Tensor],
        spec: TensorSpec | None = None,
        shift_weight: float = 0.5,
        *,
        observation_key: NestedKey = "observation",
        loc_key: NestedKey = "loc",
        scale_key: NestedKey = "scale",
        shift_key: NestedKey = "shift_distance",
        action_key: NestedKey = "action",
        prediction_key: NestedKey = "predicted_observation",
        exploration_scale_key: NestedKey = "exploration_scale",
        log_prob_key: NestedKey = "action_log_prob",
        action_projection: Callable[[Tensor], Tensor] | None = None,
        device: torch.device | None = None,
    ):
        if not callable(transition_model):
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
        self.shift_key = shift_key
        self.action_key = action_key
        self.prediction_key = prediction_key
        self.exploration_scale_key = exploration_scale_key
        self.log_prob_key = log_prob_key
        self.in_keys = [observation_key, loc_key, scale_key, shift_key]
        self.out_keys = [action_key, exploration_scale_key, log_prob_key, prediction_key]
        super().__init__()
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

    def _get(self, tensordict: TensorDictBase, key: NestedKey, what: str, kwarg: str) -> Tensor:
        value = tensordict.get(key, None)
        if value is None:
            raise KeyError(self._MISSING_KEY_ERR.format(key=key, what=what, kwarg=kwarg))
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
        if self._spec is not None:
            action = self._spec[self.action_key].project(action)
        if self.action_projection is not None:
            action = self.action_projection(action)
        return action

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Samples a_t by Eq. 10 (RANDOM mode) and writes ŝ_{t+1} (all modes)."""
        loc = self._get(tensordict, self.loc_key, "μ(s), the ensemble mean of Eq. 9", "loc_key")
        observation = self._get(
            tensordict,
            self.observation_key,
            "s_t, input of the transition model",
            "observation_key",
        )
        if loc.ndim < 1:
            raise ValueError(
                f"ShiftAwareNoise: {self.loc_key!r} must have a trailing action dim [*B, A], "
                "got a scalar. Fix: unsqueeze(-1) the actor output."
            )
        batch = tuple(loc.shape[:-1])
        self._check(
            self.observation_key,
            observation.shape[:-1],
            batch,
            f"[*B, S] with the batch dims *B of {self.loc_key!r} {tuple(loc.shape)}",
            "give the observation a trailing feature dim and the same batch dims as loc",
            what="batch dims",
        )
        random = exploration_type() in (ExplorationType.RANDOM, None)
        if random:
            scale = self._get(
                tensordict, self.scale_key, "σ(s), the ensemble std of Eq. 9", "scale_key"
            )
            self._check(
                self.scale_key,
                scale.shape,
                loc.shape,
                f"per-dimension std matching {self.loc_key!r}",
                "write one std per action dim (expand a shared std to loc's shape)",
            )
            shift = tensordict.get(self.shift_key, None)
            if shift is None:  # first step / no ShiftDistance transform: d_t = 0
                variance = scale.pow(2)
            else:
                self._check(
                    self.shift_key,
                    shift.shape,
                    (*batch, 1),
                    "d_t of Eq. 10, one scalar per env",
                    "append ShiftDistance() to the env, or unsqueeze(-1) the distance",
                )
                weight = self.shift_weight.to(loc.dtype)
                variance = scale.pow(2) + weight * shift.to(loc.dtype)  # Eq. (10)
            std = variance.clamp_min(self._MIN_VARIANCE).sqrt()
            action = self._project(loc + std * torch.randn_like(loc))
            log_prob = gaussian_log_prob(action, loc, std)
            tensordict.set(self.exploration_scale_key, std)
            tensordict.set(self.log_prob_key, log_prob)
        else:
            action = self._project(loc)
        tensordict.set(self.action_key, action)
        prediction = self.transition_model(observation, action)  # Alg. 1 l.5, ŝ_{t+1}
        self._check(
            self.prediction_key,
            prediction.shape,
            observation.shape,
            f"transition_model output ŝ_(t+1) must have the shape of {self.observation_key!r}",
            "make transition_model(observation, action) return [*B, obs_dim]",
        )
        tensordict.set(self.prediction_key, prediction)
        return tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(shift_weight={self.shift_weight.item():g}, "
            f"in_keys={self.in_keys}, out_keys={self.out_keys}, "
            f"projected={self._spec is not None})"
        )
