"""Cal-QL's Monte-Carlo bound on the recipe's data.

``D_offline`` once, ``D_online`` per finished episode (Nakamoto et al. 2023; the ``calql``
critic).

:class:`MonteCarloLabels` is what a learner on ``critic=calql`` (``algo=calql``, and
``algo=dual critic=calql``) owns: built with the learner, it labels ``D_offline`` with
``mc_return = monte_carlo_returns(data, critic.discount, sparse_failure_reward=...)``
and rebuilds the run's offline buffer (the replay buffer that mixes it with ``D_online``
is built after the learner); online, :meth:`MonteCarloLabels.online_transitions` holds
the transitions of the episode in progress and releases each finished episode with its
returns-to-go, as Cal-QL's code adds whole trajectories. An episode still running when
the budget ends never reaches the buffer; one cut by a checkpoint's cut point or a resume
ends at the cut (:meth:`MonteCarloLabels.cut`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
from tensordict import TensorDictBase

from torchrl_dual.data import monte_carlo_returns
from torchrl_dual.recipe.settings.structured import RecipeSettings

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.learner import RunContext

MC_RETURN = "mc_return"
"""The key of the Monte-Carlo bound in D_offline and D_online (``CalQLLoss``'s default)."""


def label_transitions(transitions: TensorDictBase, settings: RecipeSettings) -> TensorDictBase:
    """``transitions`` with their Monte-Carlo returns-to-go under :data:`MC_RETURN`."""
    transitions.set(
        MC_RETURN,
        monte_carlo_returns(
            transitions,
            settings.critic.discount,
            sparse_failure_reward=settings.critic.sparse_failure_reward,
        ).to(transitions["next", "reward"].dtype),
    )
    return transitions


class MonteCarloLabels:
    """The bound of ``run``'s offline data (labelled on construction) and online episodes.

    Args:
        run (RunContext): the run, whose ``data.transitions`` gain :data:`MC_RETURN` and whose
            ``offline_buffer`` is rebuilt from them; build it in the learner's
            ``__init__`` (before the run's replay buffer exists).
    """

    def __init__(self, run: RunContext) -> None:
        self.settings = run.settings
        label_transitions(run.data.transitions, run.settings)
        run.refresh_offline_buffer()
        self.pending: TensorDictBase | None = None  # the online episode in progress

    def online_transitions(self, transitions: TensorDictBase) -> TensorDictBase:
        """The finished episodes among the held and new ``transitions``, with their returns-to-go.

        The unfinished tail is held until its episode ends.
        """
        if self.pending is not None:
            transitions = torch.cat([self.pending, transitions])
        done = transitions["next", "done"].reshape(-1)
        if not done.any():
            self.pending = transitions
            return transitions[:0]
        end = int(done.nonzero().max()) + 1
        self.pending = transitions[end:] if end < len(transitions) else None
        return label_transitions(transitions[:end].clone(), self.settings)

    def state_dict(self) -> dict[str, Any]:
        """The held (unfinished) episode, ``{"pending": TensorDict or None}``."""
        return {"pending": self.pending}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores the held episode from :meth:`state_dict`."""
        self.pending = state.get("pending")

    def cut(self) -> None:
        """Ends the held episode at its last transition, as a new collector starts a new episode.

        It is marked truncated and done, and released with the next finished
        episode, under its own id
        (:meth:`~torchrl_dual.recipe.Learner.collector_started`: each checkpoint's cut
        point and a resume).
        """
        if self.pending is not None:
            for flag in ("truncated", "done"):
                self.pending["next", flag][-1] = True
