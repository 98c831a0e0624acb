"""A continuous one-hot action interface for discrete-action environments."""

from __future__ import annotations

import torch
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite, TensorSpec
from torchrl.envs import Transform


class ContinuousOneHotAction(Transform):
    """Lets a continuous policy drive a discrete (one-hot) action env through an argmax.

    The policy writes a float vector ``action`` of size ``num_actions``; the inverse
    transform hands the wrapped env the one-hot encoding of its argmax (ties go to the
    lowest index, as :func:`torch.argmax`). The action spec seen by the policy becomes a
    :class:`~torchrl.data.Bounded` float32 box ``[low, high]^num_actions`` (``[0, 1]`` by
    default, the range of one-hot vectors stored in offline data), so
    ``action_spec.rand()`` gives a uniformly random discrete action.

    As with every inverse transform, the rollout stores the policy's float vector, not
    the one-hot the env received.

    Args:
        num_actions (int): size of the discrete action space.

    Keyword Args:
        low (float): lower bound of the continuous box. Defaults to ``0.0``.
        high (float): upper bound of the continuous box. Defaults to ``1.0``.
        action_key (NestedKey): the action entry. Defaults to ``"action"``.
        categorical (bool): if ``True`` the env receives the argmax index (for envs built
            with ``categorical_action_encoding=True``) instead of a one-hot. Defaults to
            ``False``.

    Examples:
        >>> from tensordict import TensorDict
        >>> t = ContinuousOneHotAction(4)
        >>> td = t.inv(TensorDict({"action": torch.tensor([0.1, 0.7, 0.2, 0.0])}))
        >>> td["action"]
        tensor([0, 1, 0, 0])
    """

    def __init__(
        self,
        num_actions: int,
        *,
        low: float = 0.0,
        high: float = 1.0,
        action_key: NestedKey = "action",
        categorical: bool = False,
    ) -> None:
        if num_actions < 2:
            raise ValueError(f"num_actions must be >= 2, got {num_actions}.")
        if not low < high:
            raise ValueError(f"Need low < high, got low={low}, high={high}.")
        super().__init__(
            in_keys=[], out_keys=[], in_keys_inv=[action_key], out_keys_inv=[action_key]
        )
        self.num_actions = int(num_actions)
        self.low = float(low)
        self.high = float(high)
        self.categorical = categorical

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        if action.shape[-1] != self.num_actions:
            raise ValueError(
                f"Expected an action vector of size {self.num_actions} on the last dim, "
                f"got shape {tuple(action.shape)}."
            )
        index = action.argmax(-1)
        if self.categorical:
            return index
        return torch.nn.functional.one_hot(index, self.num_actions)

    def _continuous_spec(self, leaf: TensorSpec) -> Bounded:
        batch = leaf.shape if self.categorical else leaf.shape[:-1]
        return Bounded(
            low=self.low,
            high=self.high,
            shape=(*batch, self.num_actions),
            dtype=torch.float32,
            device=leaf.device,
        )

    def transform_action_spec(self, action_spec: TensorSpec) -> TensorSpec:
        """The policy's action spec: a ``Bounded`` float box of ``num_actions`` in ``[low, high]``.

        Args:
            action_spec (TensorSpec): the env's one-hot (or categorical) action spec, or a
                ``Composite`` holding it under ``action_key``.

        Returns:
            The same structure with the action leaf replaced by the continuous box.
        """
        if not isinstance(action_spec, Composite):
            return self._continuous_spec(action_spec)
        action_spec = action_spec.clone()
        key = self.in_keys_inv[0]
        action_spec[key] = self._continuous_spec(action_spec[key])
        return action_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(num_actions={self.num_actions}, low={self.low}, "
            f"high={self.high}, categorical={self.categorical})"
        )
