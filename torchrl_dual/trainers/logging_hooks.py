"""DUAL's logging hooks for TorchRL's :class:`~torchrl.trainers.Trainer`.

* :class:`DUALSignalsLogHook` (``pre_steps_log``): of each collected batch, the signals
  DUAL's acting policy wrote (Eq. 9's epistemic std and its share of the executed
  variance, Eq. 10's shift distance ``d_t`` and executed std), through
  :func:`~torchrl_dual.modules.exploration_signals`, the recipe's own reduction;
* :class:`NormalizedScoreLogHook` (``post_steps_log``): every ``interval`` collected
  batches, the deterministic policy's evaluation, with D4RL's normalized score
  ``100 (R − R_random) / (R_expert − R_random)``.

The trainer logs what they return under their keys (``Trainer._log``: every logger's
``log_scalar``, at the trainer's ``log_interval``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from tensordict import TensorDictBase
from torchrl.trainers import Trainer, TrainerHookBase

from torchrl_dual.data import normalized_score
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.modules import exploration_signals

__all__ = ["DUALSignalsLogHook", "NormalizedScoreLogHook"]


class DUALSignalsLogHook(TrainerHookBase):
    """Logs DUAL's online signals of each collected batch (Eq. 9-10).

    Args:
        prefix: put before each signal's name in the log. Defaults to ``"dual/"``.
        log_pbar: also show the signals in the trainer's progress bar.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.trainers import DUALSignalsLogHook
        >>> batch = TensorDict(shift_distance=torch.full((8, 1), 0.25), batch_size=[8])
        >>> DUALSignalsLogHook()(batch)
        {'dual/shift_distance': 0.25}
    """

    def __init__(self, prefix: str = "dual/", log_pbar: bool = False) -> None:
        self.prefix = prefix
        self.log_pbar = log_pbar

    def __call__(self, batch: TensorDictBase) -> dict[str, Any] | None:
        """The batch's exploration signals under ``prefix``, or ``None`` if it has none.

        Args:
            batch (TensorDictBase): a collected batch; its signals are read by
                :func:`~torchrl_dual.modules.exploration_signals`.

        Returns:
            ``{prefix + name: value}`` (plus ``"log_pbar": True`` when ``log_pbar``), or ``None``
            when the batch carries no signal.
        """
        signals = exploration_signals(batch)
        if not signals:
            return None
        out: dict[str, Any] = {f"{self.prefix}{k}": v for k, v in signals.items()}
        if self.log_pbar:
            out["log_pbar"] = True
        return out

    def state_dict(self) -> dict[str, Any]:
        """An empty dict: the hook holds no state."""
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Does nothing: the hook holds no state.

        Args:
            state_dict (dict): ignored.
        """
        pass

    def register(self, trainer: Trainer, name: str = "dual_signals") -> None:
        """Registers the hook at the trainer's ``pre_steps_log``.

        Args:
            trainer (Trainer): the TorchRL trainer.
            name (str): unused (the hook has no state to checkpoint).
        """
        trainer.register_op("pre_steps_log", self)


class NormalizedScoreLogHook(TrainerHookBase):
    """Evaluates the policy every ``interval`` collected batches and logs its score.

    Args:
        evaluate: runs the evaluation and returns its numbers by name, at least
            ``"normalized_score"`` (the recipe's evaluators do; :meth:`from_episodes`
            builds one from Gymnasium episodes and D4RL's references).
        interval: collected batches between evaluations (the first is after
            ``interval`` batches).
        prefix: put before each name in the log. Defaults to ``"eval/"``.

    The number of batches seen is its ``state_dict``, so a resumed trainer evaluates on
    the same schedule.

    Example:
        >>> from torchrl_dual.trainers import NormalizedScoreLogHook
        >>> hook = NormalizedScoreLogHook(lambda: {"normalized_score": 42.0}, interval=2)
        >>> hook(None) is None, hook(None)
        (True, {'eval/normalized_score': 42.0})
    """

    def __init__(
        self,
        evaluate: Callable[[], Mapping[str, float]],
        interval: int,
        prefix: str = "eval/",
    ) -> None:
        if interval < 1:
            raise ValueError(f"interval must be >= 1 collected batch, got {interval}")
        self.evaluate = evaluate
        self.interval = interval
        self.prefix = prefix
        self.batches = 0

    @classmethod
    def from_episodes(
        cls,
        make_env: Callable[[], Any],
        policy: Any,
        num_episodes: int,
        *,
        random_return: float,
        expert_return: float,
        interval: int,
        **evaluate_kwargs: Any,
    ) -> NormalizedScoreLogHook:
        """Builds the hook that scores deterministic evaluation episodes of ``policy``.

        ``num_episodes`` episodes run side by side
        (:func:`~torchrl_dual.evaluation.evaluate_episodes`, which takes
        ``observation_fn``, ``action_fn``, ``seed`` and ``device`` as keywords),
        scored against D4RL's ``ref_min_score`` / ``ref_max_score``
        (:func:`~torchrl_dual.data.normalized_score`).

        Example:
            >>> import gymnasium as gym, torch
            >>> from tensordict.nn import TensorDictModule
            >>> from torchrl_dual.trainers import NormalizedScoreLogHook
            >>> still = TensorDictModule(lambda o: torch.zeros(*o.shape[:-1], 1),
            ...     in_keys=["observation"], out_keys=["action"])
            >>> hook = NormalizedScoreLogHook.from_episodes(
            ...     lambda: gym.make("Pendulum-v1", max_episode_steps=5), still, 2,
            ...     random_return=-50.0, expert_return=0.0, interval=1,
            ...     observation_fn=lambda o: o)
            >>> sorted(hook(None))
            ['eval/normalized_score', 'eval/return']
        """
        kept: list = []  # the envs, built at the first evaluation

        def evaluate() -> dict[str, float]:
            returns = evaluate_episodes(
                make_env, policy, num_episodes, envs=kept, **evaluate_kwargs
            )
            mean = float(np.mean(returns))
            return {
                "normalized_score": float(normalized_score(mean, random_return, expert_return)),
                "return": mean,
            }

        return cls(evaluate, interval)

    def __call__(self, batch: TensorDictBase | None) -> dict[str, float] | None:
        """Counts a collected batch and, every ``interval`` batches, evaluates.

        Args:
            batch (TensorDictBase or None): the collected batch (only counted).

        Returns:
            ``{prefix + name: float}`` of every number ``evaluate()`` returned on an evaluation
            batch, else ``None``.

        Raises:
            KeyError: ``evaluate()`` returned no ``"normalized_score"``.
        """
        self.batches += 1
        if self.batches % self.interval:
            return None
        result = self.evaluate()
        if "normalized_score" not in result:
            raise KeyError(
                f"NormalizedScoreLogHook: evaluate() returned {sorted(result)}, without "
                "'normalized_score'; return it (NormalizedScoreLogHook.from_episodes does)."
            )
        return {f"{self.prefix}{k}": float(v) for k, v in result.items()}

    def state_dict(self) -> dict[str, Any]:
        """The number of batches seen, ``{"batches": int}``."""
        return {"batches": self.batches}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restores the number of batches seen from :meth:`state_dict`.

        Args:
            state_dict (dict): ``{"batches": int}``.
        """
        self.batches = int(state_dict["batches"])

    def register(self, trainer: Trainer, name: str = "normalized_score") -> None:
        """Registers the hook as a trainer module (checkpointed) and at ``post_steps_log``.

        Args:
            trainer (Trainer): the TorchRL trainer.
            name (str): the module's name in the trainer's state dict.
        """
        trainer.register_module(name, self)
        trainer.register_op("post_steps_log", self)
