"""Shift-aware exploration noise of DUAL (Eq. 10, Alg. 1 "Sample a_t ~ ...")."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.data.tensor_specs import BoundedContinuous, Composite, TensorSpec

from torchrl_dual._utils import is_deterministic, read_key, write_key
from torchrl_dual.modules._gaussian import gaussian_log_prob

DEFAULT_SHIFT_WEIGHT = 0.5
"""λ of Eq. (10) by default (the paper's; ``algo/dual.yaml`` sets the recipe's)."""

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
    (Algorithm 1 l. 11). Alg. 1 writes the same sample as
    ``a_t ~ π̂(·|s_t) + λ N(0, d_t)``; this module follows Eq. 10 and adds ``λ d_t`` to
    the variance.

    ``ŝ_t`` is read from ``expected_observation``, written by the
    :class:`~torchrl_dual.modules.TransitionModel` (on its own in a
    :class:`~tensordict.nn.TensorDictSequential` before this module, or inside
    :class:`~torchrl_dual.modules.LaplaceEnsembleActor` ``(transition_model=...)``, which
    answers the policy and transition queries in one trunk pass). That module reads the
    previous step carried by the :class:`~torchrl_dual.transforms.PreviousTransition` env
    transform and writes ``ŝ_t = s_t`` (``d_t = 0``) right after a reset.
    :func:`~torchrl_dual.modules.make_dual_policy` assembles the three.

    Steps of :meth:`forward`:

    1. Under ``ExplorationType.RANDOM`` (or unset): compute and write ``shift_distance``
       ``d_t`` (``[*B, 1]``); sample ``a = loc + sqrt(scale² + λ d) · ε`` (Eq. 10); project it
       onto the action spec (if any); write ``action``, the total std
       ``exploration_scale`` and, with ``return_log_prob=True``, ``action_log_prob``
       (Normal log-density of the executed, projected action summed over the action
       dim). ``scale`` is left as the Eq. 9 ensemble std.
    2. Under DETERMINISTIC / MODE / MEAN: ``action = loc`` (projected), with
       ``shift_distance = 0`` and ``exploration_scale = 0`` (no noise; ŝ_t is not read),
       so the module writes its ``out_keys`` in every mode.

    **Beyond the paper: a floor for** ``d_t``. A learned transition model is never exact,
    so ``d_t`` is positive on the very dynamics it was fitted on (measured on PointMaze
    U-maze: 0.27 on ``D_offline``, 0.31 online without a shift, 0.39-0.47 under the
    shifts of ``env.shift``; ``benchmarks/studies/shift_signal.py``). With ``shift_floor`` ``d_0``
    the variance is ``σ² + λ max(d_t − d_0, 0)``: the model's in-distribution error no
    longer adds noise everywhere, only the excess does. ``d_0 = 0`` (the default) is Eq. 10;
    ``shift_distance`` stays the raw ``d_t`` either way.

    **Beyond the paper: a constant variance** ``v_c`` (``extra_variance``), added to every
    action's variance: ``σ² + v_c + λ max(d_t − d_0, 0)``. With ``λ = 0`` and ``v_c`` set
    to ``λ`` times the typical ``d_t`` it is the control for Eq. 10: the same amount of
    extra noise, independent of the state. ``v_c = 0`` (the default) is Eq. 10.

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
    ``expected_observation``     ``[*B, S]``   ŝ_t (input; optional when λ = 0)
    ``shift_distance``           ``[*B, 1]``   d_t (output, RANDOM only)
    ``action``                   ``[*B, A]``   executed a_t (output)
    ``exploration_scale``        ``[*B, A]``   sqrt(σ² + v_c + λ d) (output, RANDOM only)
    ``action_log_prob``          ``[*B]``      log N(a_t; μ, σ² + λ d) (output, RANDOM and
                                               ``return_log_prob=True`` only)
    ===========================  ============  ==============================================

    Args:
        spec: action spec (or a Composite holding ``action_key``) used to project the
            action; ``None`` to skip projection or to set it later via :attr:`spec`.
        shift_weight: λ of Eq. 10 (a buffer, so it is checkpointed). Defaults to ``0.5``.
            With ``λ = 0`` and no ``expected_observation`` the shift term is skipped.
        shift_floor: ``d_0`` above (a buffer; set it later with ``shift_floor.fill_``,
            e.g. to the transition model's mean error on the offline data). Defaults to
            ``0.0`` (Eq. 10).
        extra_variance: ``v_c`` above, ``>= 0`` (a plain attribute, set from the config;
            not in the state dict). Defaults to ``0.0`` (Eq. 10).

    Keyword Args:
        observation_key, loc_key, scale_key, expected_observation_key, shift_key,
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
        >>> noise = ShiftAwareNoise(Bounded(-1.0, 1.0, shape=(2,)), shift_weight=0.5)
        >>> td = TensorDict(
        ...     observation=torch.ones(4, 2), loc=torch.zeros(4, 2),
        ...     scale=torch.full((4, 2), 0.1), expected_observation=torch.zeros(4, 2),
        ...     batch_size=[4],
        ... )
        >>> td = noise(td)  # ŝ_t = (0, 0), s_t = (1, 1): d_t = sqrt(2)
        >>> td["shift_distance"][0]
        tensor([1.4142])
        >>> td["exploration_scale"][0]  # sqrt(0.1**2 + 0.5 * sqrt(2))
        tensor([0.8468, 0.8468])
        >>> td["action"].shape
        torch.Size([4, 2])
        >>> floored = ShiftAwareNoise(Bounded(-1.0, 1.0, shape=(2,)), 0.5, shift_floor=1.0)
        >>> floored(td.exclude("action"))["exploration_scale"][0]  # sqrt(0.01 + 0.5 * 0.4142)
        tensor([0.4659, 0.4659])
        >>> constant = ShiftAwareNoise(Bounded(-1.0, 1.0, shape=(2,)), 0.0, extra_variance=0.15)
        >>> constant(td.exclude("action"))["exploration_scale"][0]  # sqrt(0.01 + 0.15)
        tensor([0.4000, 0.4000])
    """

    _SHAPE_ERR = (
        "ShiftAwareNoise: {key!r} has {what} {got}, expected {expected} ({why}). Fix: {fix}"
    )
    # Lower bound on the Eq. 10 variance so that σ = 0 and d = 0 stay finite.
    _MIN_VARIANCE = 1e-12

    def __init__(
        self,
        spec: TensorSpec | None = None,
        shift_weight: float = DEFAULT_SHIFT_WEIGHT,
        *,
        shift_floor: float = 0.0,
        extra_variance: float = 0.0,
        observation_key: NestedKey = "observation",
        loc_key: NestedKey = "loc",
        scale_key: NestedKey = "scale",
        expected_observation_key: NestedKey = "expected_observation",
        shift_key: NestedKey = "shift_distance",
        action_key: NestedKey = "action",
        exploration_scale_key: NestedKey = "exploration_scale",
        log_prob_key: NestedKey = "action_log_prob",
        action_projection: Callable[[Tensor], Tensor] | None = None,
        return_log_prob: bool = False,
        device: torch.device | None = None,
    ):
        if spec is not None and not isinstance(spec, TensorSpec):
            raise TypeError(
                f"ShiftAwareNoise: spec must be a TorchRL TensorSpec (the action spec), got "
                f"{type(spec).__name__}. ŝ_t comes from a TransitionModel placed before this module."
            )
        if not float(shift_weight) >= 0:
            raise ValueError(
                f"ShiftAwareNoise: shift_weight (λ of Eq. 10) must be >= 0, got {shift_weight}."
            )
        if not float(shift_floor) >= 0:
            raise ValueError(
                f"ShiftAwareNoise: shift_floor (d_0, subtracted from d_t) must be >= 0, got "
                f"{shift_floor}."
            )
        if not float(extra_variance) >= 0:
            raise ValueError(
                f"ShiftAwareNoise: extra_variance (a constant added to the variance) must be "
                f">= 0, got {extra_variance}."
            )
        self.observation_key = observation_key
        self.loc_key = loc_key
        self.scale_key = scale_key
        self.expected_observation_key = expected_observation_key
        self.shift_key = shift_key
        self.action_key = action_key
        self.exploration_scale_key = exploration_scale_key
        self.log_prob_key = log_prob_key
        self.in_keys = [observation_key, loc_key, scale_key, expected_observation_key]
        self.out_keys = [action_key, shift_key, exploration_scale_key]
        if return_log_prob:
            self.out_keys.append(log_prob_key)
        super().__init__()
        self.return_log_prob = return_log_prob
        self.action_projection = action_projection
        self.extra_variance = float(extra_variance)
        self.register_buffer(
            "shift_weight", torch.tensor(float(shift_weight), dtype=torch.float32, device=device)
        )
        self._uses_shift = float(shift_weight) > 0  # host copy of λ > 0: no device read per step
        self.register_load_state_dict_post_hook(_refresh_uses_shift)
        self.register_buffer(
            "shift_floor", torch.tensor(float(shift_floor), dtype=torch.float32, device=device)
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
        """``ŝ_t``, written by a :class:`~torchrl_dual.modules.TransitionModel` upstream."""
        if self._uses_shift:
            expected = read_key(
                tensordict,
                self.expected_observation_key,
                "ShiftAwareNoise (ŝ_t, the transition model's prediction of s_t)",
                "Place a TransitionModel before ShiftAwareNoise, or pass "
                "LaplaceEnsembleActor(..., transition_model=...) (make_dual_policy does this), "
                "and append PreviousTransition() to the env. Or set shift_weight=0.",
            )
        else:
            expected = tensordict.get(self.expected_observation_key, None)
        if expected is not None:
            self._check(
                self.expected_observation_key,
                expected.shape,
                observation.shape,
                f"ŝ_t has the shape of {self.observation_key!r}",
                "predict one next observation per env",
            )
        return expected

    def step(self, frames: int = 1) -> None:
        """Does nothing: Eq. 10's λ is a constant.

        Present so that loops written for TorchRL's annealed exploration modules
        (``policy[-1].step(frames)``, as for ``AdditiveGaussianModule``) run
        unchanged with a DUAL policy.

        Examples:
            >>> noise = ShiftAwareNoise(shift_weight=0.5)
            >>> noise.step(1000)
            >>> float(noise.shift_weight)
            0.5
        """

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Writes d_t and samples a_t by Eq. 10 (RANDOM mode); a_t = μ otherwise."""
        loc = read_key(
            tensordict,
            self.loc_key,
            "ShiftAwareNoise (μ(s), the ensemble mean of Eq. 9)",
            self._fix("loc_key"),
        )
        if loc.ndim < 1:
            raise ValueError(
                f"ShiftAwareNoise: {self.loc_key!r} must have a trailing action dim [*B, A], "
                "got a scalar. Fix: unsqueeze(-1) the actor output."
            )
        if is_deterministic():  # a_t = μ: no noise, d_t not used
            write_key(tensordict, self.action_key, self._project(loc))
            write_key(tensordict, self.shift_key, loc.new_zeros(*loc.shape[:-1], 1))
            write_key(tensordict, self.exploration_scale_key, torch.zeros_like(loc))
            if self.return_log_prob:  # the policy's N(μ, σ²) density at its mode
                scale = read_key(tensordict, self.scale_key, "ShiftAwareNoise (σ(s))")
                action = tensordict.get(self.action_key)
                write_key(tensordict, self.log_prob_key, gaussian_log_prob(action, loc, scale))
            return tensordict
        scale = read_key(
            tensordict,
            self.scale_key,
            "ShiftAwareNoise (σ(s), the ensemble std of Eq. 9)",
            self._fix("scale_key"),
        )
        self._check(
            self.scale_key,
            scale.shape,
            loc.shape,
            f"per-dimension std matching {self.loc_key!r}",
            "write one std per action dim (expand a shared std to loc's shape)",
        )
        observation = read_key(
            tensordict, self.observation_key, "ShiftAwareNoise (s_t)", self._fix("observation_key")
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
            write_key(tensordict, self.shift_key, shift)  # d_t
            excess = (shift - self.shift_floor).clamp_min(0.0)  # d_t itself when d_0 = 0
            variance = torch.addcmul(variance, excess, self.shift_weight)  # Eq. (10)
        else:  # λ = 0: no ŝ_t, d_t written as 0
            write_key(tensordict, self.shift_key, loc.new_zeros(*loc.shape[:-1], 1))
        if self.extra_variance:
            variance = variance + self.extra_variance
        std = variance.clamp_min(self._MIN_VARIANCE).sqrt()
        action = self._project(torch.addcmul(loc, std, torch.randn_like(loc)))
        write_key(tensordict, self.action_key, action)
        write_key(tensordict, self.exploration_scale_key, std)
        if self.return_log_prob:
            write_key(tensordict, self.log_prob_key, gaussian_log_prob(action, loc, std))
        return tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(shift_weight={self.shift_weight.item():g}, "
            f"shift_floor={self.shift_floor.item():g}, extra_variance={self.extra_variance:g}, "
            f"in_keys={self.in_keys}, out_keys={self.out_keys}, "
            f"projected={self._spec is not None})"
        )


def _refresh_uses_shift(module: ShiftAwareNoise, incompatible_keys) -> None:
    """After ``load_state_dict``: whether the loaded λ is positive, on the host."""
    module._uses_shift = float(module.shift_weight) > 0
