"""OFF2ON's density-ratio estimator.

Lee et al. 2022, "Offline-to-Online Reinforcement Learning via Balanced Replay and
Pessimistic Q-Ensemble", CoRL, arXiv:2107.00591.

Balanced replay samples a transition in proportion to ``w(s, a) = d_online(s, a) /
d_offline(s, a)``, which a network learns from the two data sets alone by the variational
(f-GAN) form of the Jensen-Shannon divergence. With ``w ≥ 0`` the network's output, the
loss of the authors' code (``shlee94/Off2OnRL``, ``rlkit/torch/sac/ours.py``) is

``L(ψ) = E_{D_offline}[−log(2 / (w_ψ + 1))] − E_{D_online}[log(2 w_ψ / (w_ψ + 1))]``,

whose pointwise minimiser is ``w = d_online / d_offline`` (set the derivative
``d_off / (w + 1) − d_on / (w (w + 1))`` to zero). Their network is an MLP on ``(s, a)``
with two hidden layers of 256 units, a ReLU on its output and the last bias set to 1
(:func:`make_density_ratio_network`), trained by Adam (lr 3e-4) on 256 offline and 256
online transitions per step, both drawn uniformly. The sampler that uses ``w`` is
:class:`~torchrl_dual.data.BalancedReplayBuffer`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.modules import MLP
from torchrl.objectives.common import LossModule

from torchrl_dual._utils import host_reads_allowed, read_loss_input

_LOG_EPS = 1e-10  # the authors' guard inside both logarithms


def make_density_ratio_network(
    observation_dim: int,
    action_dim: int,
    *,
    num_cells: Sequence[int] = (256, 256),
    in_keys: Sequence[NestedKey] = ("observation", "action"),
    out_key: NestedKey = "density_ratio",
) -> TensorDictModule:
    """OFF2ON's density-ratio network ``w_ψ(s, a) ≥ 0``.

    An MLP on the concatenated ``(s, a)``, output bias 1, then a ReLU; writes
    ``out_key`` ``[*B, 1]``.

    Args:
        observation_dim (int): ``dim(s)``.
        action_dim (int): ``dim(a)``.

    Keyword Args:
        num_cells (sequence of int): the hidden layers' widths. Defaults to ``(256, 256)``
            (OFF2ON's).
        in_keys (sequence of NestedKey): the state and action keys. Defaults to
            ``("observation", "action")``.
        out_key (NestedKey): the output key. Defaults to ``"density_ratio"``.

    Returns:
        TensorDictModule: the network, its last bias initialised to 1 (``w ≈ 1`` at first).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> net = make_density_ratio_network(3, 2, num_cells=(8,))
        >>> td = TensorDict(observation=torch.randn(4, 3), action=torch.randn(4, 2), batch_size=[4])
        >>> w = net(td)["density_ratio"]
        >>> w.shape, bool((w >= 0).all())
        (torch.Size([4, 1]), True)
    """
    mlp = MLP(
        in_features=observation_dim + action_dim,
        out_features=1,
        num_cells=list(num_cells),
        activation_class=nn.ReLU,
    )
    with torch.no_grad():
        mlp[-1].bias.fill_(1.0)
    return TensorDictModule(_RectifiedMLP(mlp), in_keys=list(in_keys), out_keys=[out_key])


class _RectifiedMLP(nn.Module):
    """``relu(mlp(concat(inputs)))``."""

    def __init__(self, mlp: nn.Module) -> None:
        super().__init__()
        self.mlp = mlp

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.mlp(torch.cat(inputs, -1)))


class DensityRatioLoss(LossModule):
    """OFF2ON's Jensen-Shannon loss for the density ratio ``w = d_online / d_offline``.

    The batch holds transitions of both data sets, told apart by the boolean
    ``tensor_keys.online`` entry (as written by
    :meth:`~torchrl_dual.data.BalancedReplayBuffer.ratio_batch`); each expectation is the
    mean over its own part, so the two parts need not be of equal size.

    Args:
        ratio_network (TensorDictModuleBase): writes ``tensor_keys.density_ratio``, which
            must be ``≥ 0`` (end it with a ReLU or Softplus, e.g.
            :func:`make_density_ratio_network`).

    Keyword Args:
        reduction (str): ``"mean"`` (default: ``L(ψ)`` above), ``"sum"`` or ``"none"``:
            one term per transition, shaped like the batch, each part's terms scaled by
            ``N / N_part`` so that their mean is ``L(ψ)`` (``"sum"`` is ``N · L(ψ)``).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> loss = DensityRatioLoss(make_density_ratio_network(3, 2, num_cells=(8,)))
        >>> td = TensorDict(observation=torch.randn(8, 3), action=torch.randn(8, 2),
        ...                 online=torch.arange(8) % 2 == 0, batch_size=[8])
        >>> out = loss(td)
        >>> out["loss_density_ratio"].backward()
        >>> sorted(out.keys())
        ['loss_density_ratio', 'ratio_offline', 'ratio_online']
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            density_ratio (NestedKey): the network's output ``w``.
                Defaults to ``"density_ratio"``.
            online (NestedKey): ``True`` for online transitions. Defaults to ``"online"``.
        """

        density_ratio: NestedKey = "density_ratio"
        online: NestedKey = "online"

    default_keys = _AcceptedKeys
    out_keys = ["loss_density_ratio", "ratio_offline", "ratio_online"]

    ratio_network: TensorDictModuleBase
    ratio_network_params: TensorDictParams
    target_ratio_network_params: TensorDictParams

    def __init__(self, ratio_network: TensorDictModuleBase, *, reduction: str = "mean") -> None:
        if reduction not in ("mean", "sum", "none"):
            raise ValueError(f"reduction must be 'mean', 'sum' or 'none', got {reduction!r}.")
        super().__init__()
        self.convert_to_functional(ratio_network, "ratio_network")
        self.reduction = reduction

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads: the ratio network's inputs and the ``online`` flag."""
        return [*self.ratio_network.in_keys, self.tensor_keys.online]

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """OFF2ON's Jensen-Shannon loss ``L(ψ)`` of the batch and the mean ratio on each part.

        Args:
            tensordict (TensorDictBase): offline and online transitions ``[*B]``, with the
                ratio network's inputs and the boolean ``online`` flag.

        Returns:
            ``loss_density_ratio`` (a scalar, or ``[*B]`` under ``reduction="none"``) and the
            detached means ``ratio_offline`` and ``ratio_online`` of ``w``.

        Raises:
            ValueError: the batch holds only offline or only online transitions.
        """
        online = read_loss_input(tensordict, self.tensor_keys.online, "online")
        td = tensordict.select(*self.ratio_network.in_keys, strict=False)
        with self.ratio_network_params.to_module(self.ratio_network):
            w = self.ratio_network(td).get(self.tensor_keys.density_ratio)
        w = w.reshape(tensordict.shape)
        online = online.reshape(w.shape).bool()
        if host_reads_allowed() and (bool(online.all()) or not bool(online.any())):
            raise ValueError(
                "DensityRatioLoss needs offline and online transitions in the batch; got "
                f"{int(online.sum())} online of {online.numel()}. Use "
                "BalancedReplayBuffer.ratio_batch() once the online buffer holds data."
            )
        # means over each part as masked sums: no data-dependent shapes (compiles whole)
        on = online.to(w.dtype)
        off = 1.0 - on
        offline_term = -torch.log(2.0 / (w + 1.0) + _LOG_EPS)  # f*(T) on D_offline
        online_term = torch.log(2.0 * w / (w + 1.0) + _LOG_EPS)  # T on D_online
        n_off, n_on = off.sum(), on.sum()
        if self.reduction == "mean":
            loss = (offline_term * off).sum() / n_off - (online_term * on).sum() / n_on
        else:  # per transition, each part's mean as a mean over the whole batch
            n = w.numel()
            loss = offline_term * off * (n / n_off) - online_term * on * (n / n_on)
            loss = loss.sum() if self.reduction == "sum" else loss
        return TensorDict(
            {
                "loss_density_ratio": loss,
                "ratio_offline": ((w * off).sum() / n_off).detach(),
                "ratio_online": ((w * on).sum() / n_on).detach(),
            },
            batch_size=[],
        )
