"""An offline data set: transitions plus the reference returns used to normalize scores."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from tensordict import TensorDictBase

from torchrl_dual.data.scores import ReturnsT, normalized_score


@dataclass
class OfflineDataset:
    """Transitions in the project layout with their score references.

    Attributes:
        transitions (TensorDictBase): flat transitions (see :mod:`torchrl_dual.data.transition_layout`).
        reference_min (float or None): return of the random reference policy.
        reference_max (float or None): return of the expert / controller reference policy.
        metadata (dict): JSON-serializable description (source, seeds, generator version...).

    Examples:
        >>> import numpy as np
        >>> from torchrl_dual.data import make_transitions
        >>> td = make_transitions(np.zeros((2, 3)), np.zeros((2, 1)), np.zeros((2, 3)),
        ...     np.zeros(2), np.zeros(2, bool), np.array([0, 1], bool), np.zeros(2, int))
        >>> data = OfflineDataset(td, reference_min=0.0, reference_max=10.0)
        >>> data.obs_dim, data.action_dim, data.normalized_score(5.0)
        (3, 1, 50.0)
        >>> head = data.without_transitions()
        >>> len(head), head.obs_dim, head.normalized_score(5.0)
        (0, 3, 50.0)
    """

    transitions: TensorDictBase
    reference_min: float | None = None
    reference_max: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def obs_dim(self) -> int:
        """The observation's size, the last dim of ``transitions["observation"]``."""
        return int(self.transitions["observation"].shape[-1])

    @property
    def action_dim(self) -> int:
        """The action's size, the last dim of ``transitions["action"]``."""
        return int(self.transitions["action"].shape[-1])

    @property
    def num_episodes(self) -> int:
        """The number of distinct ``episode`` ids in the transitions."""
        return int(self.transitions["episode"].unique().numel())

    def __len__(self) -> int:
        return int(self.transitions.batch_size[0])

    def without_transitions(self) -> OfflineDataset:
        """The data set's description without its transitions.

        An empty slice keeps the keys and dims: references and metadata, a few
        kilobytes to send to a worker process that needs what the data set says of
        its env (e.g. the observation normalization of a Minari kit), not the data.
        """
        return OfflineDataset(
            self.transitions[:0].clone(),
            self.reference_min,
            self.reference_max,
            dict(self.metadata),
        )

    def normalized_score(self, returns: ReturnsT) -> ReturnsT:
        """``100 * (R - reference_min) / (reference_max - reference_min)``."""
        if self.reference_min is None or self.reference_max is None:
            source = self.metadata.get("dataset_id") or self.metadata.get("source", "this dataset")
            raise ValueError(
                f"No reference scores for {source}: reference_min={self.reference_min}, "
                f"reference_max={self.reference_max}. Pass them to "
                "torchrl_dual.data.normalized_score(returns, random_return, expert_return) yourself."
            )
        return normalized_score(returns, self.reference_min, self.reference_max)
