"""Env-side carry of the previous transition ``(s_{t-1}, a_{t-1})`` for DUAL Eq. 10."""

from __future__ import annotations

import torch
from tensordict import NestedKey, TensorDictBase
from torch import Tensor
from torchrl.data.tensor_specs import Binary, Composite, TensorSpec, Unbounded
from torchrl.envs.transforms import Transform

from torchrl_dual._utils import read_key

__all__ = ["PreviousTransition"]


class PreviousTransition(Transform):
    r"""Hands the policy at step ``t`` the state and executed action of step ``t − 1``.

    DUAL's shift signal (Eq. 10, Algorithm 1 l. 11) is ``d_t = ‖ŝ_t − s_t‖₂`` with
    ``ŝ_t = p(s' | s_{t-1}, a_{t-1}; θ)``. The policy computes it when it acts at ``t``
    (a :class:`~torchrl_dual.modules.TransitionModel` reads the keys below and writes
    ``ŝ_t``; given to :class:`~torchrl_dual.modules.LaplaceEnsembleActor` as
    ``transition_model=``, it answers in the same trunk pass as the policy query), so the
    env only has to remember the previous step. During ``env.step`` this transform copies the
    *root* ``observation`` (``s_t``) and the executed ``action`` (``a_t``) into ``"next"``:

    ==============================  ============  ======================================
    key written in ``"next"``       shape         value
    ==============================  ============  ======================================
    ``previous_observation``        ``[*B, S]``   ``s_t``
    ``previous_action``             ``[*B, A]``   ``a_t``, the action the env executed
    ``previous_valid``              ``[*B, 1]``   ``True``
    ==============================  ============  ======================================

    :func:`~torchrl.envs.utils.step_mdp` moves them to the root, where the policy reads
    them at ``t + 1``. At reset they are zeros and ``previous_valid = False`` (no previous
    step: ``d_0 = 0``); for partial resets the env keeps the other entries.

    Apply it to the outer env (e.g. ``TransformedEnv(ParallelEnv(...),
    PreviousTransition())``): the root action is only available there.

    Keyword Args:
        observation_key (NestedKey): the observation to carry. Defaults to ``"observation"``.
        action_key (NestedKey): the action to carry. Defaults to ``"action"``.
        previous_observation_key, previous_action_key, previous_valid_key (NestedKey):
            output keys. Default to ``"previous_observation"``, ``"previous_action"`` and
            ``"previous_valid"``.

    Examples:
        >>> import torch
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> from torchrl_dual.transforms import PreviousTransition
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), PreviousTransition())
        >>> td = env.reset()
        >>> td["previous_valid"], td["previous_action"]
        (tensor([False]), tensor([0.]))
        >>> td["action"] = torch.tensor([0.5])
        >>> nxt = env.step(td)["next"]
        >>> nxt["previous_valid"], nxt["previous_action"]
        (tensor([True]), tensor([0.5000]))
        >>> bool((nxt["previous_observation"] == td["observation"]).all())
        True
    """

    def __init__(
        self,
        *,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        previous_observation_key: NestedKey = "previous_observation",
        previous_action_key: NestedKey = "previous_action",
        previous_valid_key: NestedKey = "previous_valid",
    ):
        super().__init__(
            in_keys=[observation_key, action_key],
            out_keys=[previous_observation_key, previous_action_key, previous_valid_key],
        )
        self.observation_key = observation_key
        self.action_key = action_key
        self.previous_observation_key = previous_observation_key
        self.previous_action_key = previous_action_key
        self.previous_valid_key = previous_valid_key

    def _read(self, tensordict: TensorDictBase, key: NestedKey, where: str) -> Tensor:
        return read_key(
            tensordict,
            key,
            f"PreviousTransition (the {where})",
            "Pass observation_key= / action_key= with the keys your env uses.",
        )

    def _action_spec(self) -> TensorSpec:
        parent = self.parent
        if parent is None:
            raise RuntimeError(
                "PreviousTransition needs the env's action spec: append it to an env "
                "(TransformedEnv(env, PreviousTransition())) before reading specs."
            )
        spec = parent.full_action_spec.get(self.action_key, None)
        if spec is None:
            raise KeyError(
                f"PreviousTransition: the env has no action {self.action_key!r} (actions: "
                f"{list(parent.full_action_spec.keys(True, True))}). Pass action_key=."
            )
        return spec

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        observation = self._read(tensordict, self.observation_key, "step input")
        action = self._read(tensordict, self.action_key, "step input")
        next_tensordict.set(self.previous_observation_key, observation.clone())
        next_tensordict.set(self.previous_action_key, action.clone())
        valid = torch.ones(
            (*next_tensordict.batch_size, 1), dtype=torch.bool, device=observation.device
        )
        next_tensordict.set(self.previous_valid_key, valid)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        observation = self._read(tensordict_reset, self.observation_key, "reset output")
        spec = self._action_spec()
        batch = tensordict_reset.batch_size
        tensordict_reset.set(self.previous_observation_key, torch.zeros_like(observation))
        tensordict_reset.set(
            self.previous_action_key,
            torch.zeros(
                (*batch, *spec.shape[len(batch) :]), dtype=spec.dtype, device=observation.device
            ),
        )
        tensordict_reset.set(
            self.previous_valid_key,
            torch.zeros((*batch, 1), dtype=torch.bool, device=observation.device),
        )
        return tensordict_reset

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        """Adds the previous observation, previous action and valid flag to the observation spec.

        Args:
            observation_spec (Composite): the env's observation spec.

        Returns:
            The spec with ``previous_observation_key`` (shaped like the observation),
            ``previous_action_key`` (shaped like the action, unbounded) and
            ``previous_valid_key`` (boolean, ``[*batch, 1]``).

        Raises:
            KeyError: the env has no ``observation_key``.
        """
        if self.observation_key not in observation_spec.keys(True, True):
            raise KeyError(
                f"PreviousTransition: the env has no observation {self.observation_key!r} "
                f"(observations: {list(observation_spec.keys(True, True))}). "
                "Pass observation_key=."
            )
        observed = observation_spec[self.observation_key]
        action = self._action_spec()
        observation_spec[self.previous_observation_key] = Unbounded(
            shape=observed.shape, dtype=observed.dtype, device=observed.device
        )
        observation_spec[self.previous_action_key] = Unbounded(
            shape=action.shape, dtype=action.dtype, device=action.device
        )
        observation_spec[self.previous_valid_key] = Binary(
            n=1,
            shape=(*observation_spec.shape, 1),
            dtype=torch.bool,
            device=observation_spec.device,
        )
        return observation_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(observation_key={self.observation_key!r}, "
            f"action_key={self.action_key!r})"
        )
