"""What DUAL's acting policy wrote into a collected batch, reduced to a few numbers.

The one home of DUAL's online signals, read by the recipe's learners (per collected batch,
``summary.json``'s ``online_signals`` and the learning-curve plot) and by
:class:`~torchrl_dual.trainers.DUALSignalsLogHook` in TorchRL's trainers.
"""

from __future__ import annotations

from tensordict import TensorDictBase
from tensordict.utils import NestedKey

__all__ = ["exploration_signals"]


def exploration_signals(
    batch: TensorDictBase,
    *,
    shift_key: NestedKey = "shift_distance",
    epistemic_key: NestedKey = "epistemic_variance",
    scale_key: NestedKey = "exploration_scale",
) -> dict[str, float]:
    """The means over ``batch`` of the signals DUAL's policy writes.

    A key the policy did not write (no :class:`~torchrl_dual.modules.ShiftAwareNoise`,
    no ensemble) gives no entry.

    * ``shift_distance``: Eq. 10's ``d_t``;
    * ``epistemic_std``: the root of the mean epistemic variance ``Var_m[μ_m(s)]`` of
      Eq. 9's ensemble;
    * ``epistemic_share``: that mean variance over the mean executed variance
      ``σ̄² + Var_m + v_c + λ d_t`` (the square of ``exploration_scale``): the part of the
      exploration noise the posterior makes;
    * ``exploration_std``: the mean executed std ``exploration_scale`` (Eq. 10).

    Args:
        batch (TensorDictBase): a collected batch, any batch shape.

    Keyword Args:
        shift_key (NestedKey): where the policy writes ``d_t``. Defaults to
            ``"shift_distance"``.
        epistemic_key (NestedKey): where it writes the epistemic variance. Defaults to
            ``"epistemic_variance"``.
        scale_key (NestedKey): where it writes the executed std. Defaults to
            ``"exploration_scale"``.

    Returns:
        dict[str, float]: the signals above that ``batch`` holds, by name.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> batch = TensorDict(epistemic_variance=torch.full((4, 2), 0.01),
        ...                    exploration_scale=torch.full((4, 2), 0.5),
        ...                    shift_distance=torch.full((4, 1), 0.2), batch_size=[4])
        >>> {k: round(v, 4) for k, v in exploration_signals(batch).items()}
        {'shift_distance': 0.2, 'epistemic_std': 0.1, 'epistemic_share': 0.04, 'exploration_std': 0.5}
        >>> exploration_signals(TensorDict(batch_size=[4]))
        {}
    """
    keys = batch.keys(True)
    signals: dict[str, float] = {}
    if shift_key in keys:
        signals["shift_distance"] = float(batch.get(shift_key).mean())
    if epistemic_key in keys:
        epistemic = batch.get(epistemic_key).mean()
        signals["epistemic_std"] = float(epistemic.sqrt())
        if scale_key in keys:
            executed = batch.get(scale_key).square().mean()
            signals["epistemic_share"] = float(epistemic / executed)
    if scale_key in keys:
        signals["exploration_std"] = float(batch.get(scale_key).mean())
    return signals
