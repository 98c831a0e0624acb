"""Env-side transition-shift signal d_t of DUAL Eq. 10."""

from __future__ import annotations

import torch
from tensordict import NestedKey, TensorDictBase
from torch import Tensor
from torchrl.data.tensor_specs import Composite, Unbounded
from torchrl.envs.transforms import Transform

__all__ = ["ShiftDistance"]


class ShiftDistance(Transform):
    r"""Writes the transition-shift distance ``d = ‖ŝ_{t+1} − s_{t+1}‖₂`` of DUAL Eq. 10.

    The policy's :class:`~torchrl_dual.modules.shift_aware.ShiftAwareNoise` writes its prediction
    ``ŝ_{t+1}`` (from ``s_t`` and the executed ``a_t``) next to the action. During
    ``env.step`` this transform reads that prediction from the *root* tensordict (the one
    holding the action) and the true ``s_{t+1}`` from the ``"next"`` tensordict, and writes

    .. math::

        d = \lVert \hat s_{t+1} - s_{t+1} \rVert_2 \quad\text{into}\quad
        \texttt{("next", shift\_distance)}, \ \text{shape } [*B, 1], \text{ float32.}

    After :func:`~torchrl.envs.utils.step_mdp` it becomes the root ``shift_distance`` that
    :class:`ShiftAwareNoise` reads at the next step (the ``d_t`` of Eq. 10 and of
    Alg. 1 "Sample a_t ~ ..."). At reset ``shift_distance = 0`` (for partial resets the env
    keeps the other entries). If the root tensordict has no prediction (a policy without
    ``ShiftAwareNoise``, random actions, :func:`~torchrl.envs.utils.check_env_specs`),
    ``d = 0``.

    Since the noise is drawn on the policy side, collectors and replay buffers store the
    executed (noisy) action, ``predicted_observation`` and ``("next", "shift_distance")``
    with each transition; an inverse transform would instead store the noiseless action.

    Apply it to the outer env (e.g. ``TransformedEnv(ParallelEnv(...), ShiftDistance())``):
    the workers of a batched env only receive the action, not the prediction.

    Keyword Args:
        observation_key (NestedKey): true next observation ``s_{t+1}`` in ``"next"``.
            Defaults to ``"observation"``.
        prediction_key (NestedKey): prediction ``ŝ_{t+1}`` in the root tensordict.
            Defaults to ``"predicted_observation"``.
        shift_key (NestedKey): output key. Defaults to ``"shift_distance"``.

    Examples:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> from torchrl_dual.transforms import ShiftDistance
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), ShiftDistance())
        >>> env.reset()["shift_distance"]
        tensor([0.])
        >>> td = env.reset()
        >>> td["action"] = env.action_spec.zero()
        >>> td["predicted_observation"] = td["observation"]  # "nothing moves"
        >>> d = env.step(td)["next", "shift_distance"]
        >>> bool(d > 0), d.shape
        (True, torch.Size([1]))
    """

    def __init__(
        self,
        *,
        observation_key: NestedKey = "observation",
        prediction_key: NestedKey = "predicted_observation",
        shift_key: NestedKey = "shift_distance",
    ):
        super().__init__(in_keys=[observation_key], out_keys=[shift_key])
        self.observation_key = observation_key
        self.prediction_key = prediction_key
        self.shift_key = shift_key

    def _zeros(self, batch_size: torch.Size, device: torch.device | None) -> Tensor:
        return torch.zeros((*batch_size, 1), dtype=torch.float32, device=device)

    def _distance(self, prediction: Tensor | None, observation: Tensor, batch_size) -> Tensor:
        if prediction is None:
            return self._zeros(batch_size, observation.device)
        if prediction.shape != observation.shape:
            raise ValueError(
                f"ShiftDistance: {self.prediction_key!r} has shape {tuple(prediction.shape)} "
                f"but the next {self.observation_key!r} has shape {tuple(observation.shape)}; "
                "they must match. Fix: make the transition model of ShiftAwareNoise return "
                "[*B, obs_dim], or set observation_key=/prediction_key= to matching keys."
            )
        error = prediction.to(torch.float32) - observation.to(torch.float32)
        return torch.linalg.vector_norm(error, dim=-1, keepdim=True)

    def _get_observation(self, next_tensordict: TensorDictBase) -> Tensor:
        observation = next_tensordict.get(self.observation_key, None)
        if observation is None:
            raise KeyError(
                f"ShiftDistance: the env output has no {self.observation_key!r} "
                f"(keys: {list(next_tensordict.keys(True, True))}). "
                "Pass observation_key=<the key the transition model predicts>."
            )
        return observation

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        observation = self._get_observation(next_tensordict)
        prediction = tensordict.get(self.prediction_key, None)
        distance = self._distance(prediction, observation, next_tensordict.batch_size)
        next_tensordict.set(self.shift_key, distance)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        device = tensordict_reset.device
        if device is None:
            device = self._get_observation(tensordict_reset).device
        tensordict_reset.set(self.shift_key, self._zeros(tensordict_reset.batch_size, device))
        return tensordict_reset

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Recomputes ``("next", shift_key)`` on stored transitions (e.g. a replay batch)."""
        next_tensordict = tensordict.get("next")
        observation = self._get_observation(next_tensordict)
        prediction = tensordict.get(self.prediction_key, None)
        distance = self._distance(prediction, observation, tensordict.batch_size)
        tensordict.set(("next", self.shift_key), distance)
        return tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.shift_key] = Unbounded(
            shape=(*observation_spec.shape, 1),
            dtype=torch.float32,
            device=observation_spec.device,
        )
        return observation_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(observation_key={self.observation_key!r}, "
            f"prediction_key={self.prediction_key!r}, shift_key={self.shift_key!r})"
        )
