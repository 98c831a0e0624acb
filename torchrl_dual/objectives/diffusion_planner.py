"""The diffusion planner's denoising loss (Eq. 3) and its pre-training driver."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams

from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.objectives._trajectory_window_loss import TrajectoryWindowLoss, masked_mean
from torchrl_dual.objectives.optim import adam
from torchrl_dual.objectives.update_loop import run_updates


class DiffusionPlannerLoss(TrajectoryWindowLoss):
    """Denoising loss of the trajectory diffusion planner, Eq. (3) of DUAL.

    For a batch of windows ``τ⁰ = (s_0, a_0, …, s_H, a_H)``:

    1. normalize states and actions with the model's fitted :class:`Normalizer`;
    2. draw ``t ~ U(0, 1)`` and ``ε ~ N(0, I)``; form ``z_t = α_t·τ⁰ + σ_t·ε``;
    3. write the known entries (``s_0``; ``a_0`` with probability
       ``action_condition_prob``) back into ``z_t`` and predict ``v̂``;
    4. return the mean of ``‖v̂ − v‖²`` over the entries that are not known, with
       ``v = α_t·ε − σ_t·τ⁰``.

    **Prediction target.** Eq. (3) regresses the noise ε. This loss regresses
    ``v`` instead. All targets share the same optimum, the posterior mean
    ``E[τ⁰ | z_t]`` (in x-space the ε-loss weighs time by ``SNR(t)`` and the
    v-loss by ``SNR(t) + 1``). ``v`` is used because progressive distillation
    needs ``x̂`` at ``t = 1``, where ``α_t = 0`` and ``x̂ = (z − σ·ε̂)/α`` from an
    ε-prediction is undefined. The one-step student also samples there.

    Args:
        model (TrajectoryDiffusion): the planner, whose normalizer is fitted (an unfitted
            one raises). The windows must have its dtype: a float64 batch for a float32
            planner is an error naming both (cast one, e.g. ``loss.double()``).

    Keyword Args:
        action_condition_prob (float): probability that ``a_0`` is also given, which
            trains the transition model ``p(s_1 | s_0, a_0)`` (Algorithm 1, line 5)
            into the same network. Defaults to ``0.5``.
        reduction (str): ``"none"`` | ``"mean"`` | ``"sum"``. Defaults to ``"mean"``.

    .. note::
        The input is a ``[batch, H + 1]`` TensorDict of windows, for instance from
        :class:`~torchrl_dual.diffusion.WindowReplayBuffer`. It needs
        ``tensor_keys.observation`` and ``tensor_keys.action``, and may hold a boolean
        ``tensor_keys.condition_mask`` of shape ``[batch, H + 1, obs_dim + action_dim]``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> layout = TrajectoryLayout(obs_dim=3, action_dim=2, horizon=4)
        >>> model = TrajectoryDiffusion(layout, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 3), torch.randn(64, 2))  # offline data
        >>> loss_fn = DiffusionPlannerLoss(model)
        >>> windows = TensorDict(
        ...     {"observation": torch.randn(8, 5, 3), "action": torch.randn(8, 5, 2)},
        ...     batch_size=[8, 5],
        ... )
        >>> loss_td = loss_fn(windows)
        >>> loss_td["loss_diffusion"].backward()
    """

    out_keys = ["loss_diffusion", "x0_error"]

    model: TrajectoryDiffusion
    model_params: TensorDictParams
    target_model_params: TensorDictParams

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        action_condition_prob: float = 0.5,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        if not 0.0 <= action_condition_prob <= 1.0:
            raise ValueError(
                f"action_condition_prob must lie in [0, 1], got {action_condition_prob}."
            )
        self.convert_to_functional(model, "model")
        self.action_condition_prob = action_condition_prob
        self.reduction = reduction

    def denoising_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Per-window loss of Eq. (3) in v-parameterisation and diagnostics."""
        with self.model_params.to_module(self.model):  # the normalizer's statistics too
            x0, mask = self._windows(self.model, tensordict)
            batch = x0.shape[:-2]
            t = torch.rand(batch, device=x0.device, dtype=x0.dtype)
            eps = torch.randn_like(x0)
            z = self.model.noise(x0, t, eps)
            x_hat, _, v_hat = self.model.predict(z, t, x0, mask)
        loss = masked_mean((v_hat - self.model.v_target(x0, t, eps)) ** 2, mask)
        metadata = {"x0_error": masked_mean((x_hat - x0) ** 2, mask).mean().detach()}
        return loss, metadata

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """The reduced denoising loss of Eq. (3) and its diagnostics.

        Args:
            tensordict (TensorDictBase): a batch of windows (see the class docstring for its keys).

        Returns:
            ``loss_diffusion`` and the detached ``x0_error`` (the mean squared error of ``x̂_0``).
        """
        loss, metadata = self.denoising_loss(tensordict)
        loss = self._reduce_loss(loss)
        return TensorDict({"loss_diffusion": loss, **metadata}, batch_size=[])


def train_planner(
    model: TrajectoryDiffusion,
    sample: Callable[[], TensorDictBase],
    num_updates: int,
    *,
    lr: float = 3e-4,
    action_condition_prob: float = 0.5,
    **kwargs,
) -> dict[str, float]:
    """Pre-trains the planner with :class:`DiffusionPlannerLoss` (Algorithm 1, lines 3-4).

    Runs ``num_updates`` Adam steps (fused where it can be) on the denoising loss of
    Eq. (3) through :func:`~torchrl_dual.objectives.run_updates`; ``model``'s weights are
    trained in place.

    Args:
        model (TrajectoryDiffusion): the planner, its normalizer fitted on the offline data.
        sample (callable): ``() -> TensorDict`` of windows ``[B, H + 1]`` with the
            observation ``[B, H + 1, obs_dim]`` and the action ``[B, H + 1, action_dim]``
            (e.g. :meth:`~torchrl_dual.diffusion.WindowReplayBuffer.sample`), called once
            per update.
        num_updates (int): gradient steps.

    Keyword Args:
        lr (float): Adam's learning rate. Defaults to ``3e-4``.
        action_condition_prob (float): probability that ``a_0`` is given too, which
            trains the transition model of Algorithm 1 line 5 into the same network
            (:class:`DiffusionPlannerLoss`). Defaults to ``0.5``.
        **kwargs: passed to :func:`~torchrl_dual.objectives.run_updates`, which takes
            the keywords that follow.
        progress (bool): show a tqdm progress bar. Defaults to ``True``.
        desc (str): the progress bar's label. Defaults to ``"planner"``.
        logger (Logger, optional): a TorchRL logger; the loss and ``x0_error``, averaged
            over each ``log_every`` updates, are logged as ``{log_prefix}{name}``.
        log_prefix (str): put before each logged name. Defaults to ``""``.
        log_every (int): updates per logged average. Defaults to ``100``.
        step_offset (int): added to the logged step. Defaults to ``0``.
        grad_clip (float, optional): gradient-norm clip. Defaults to ``1.0``; ``None``
            turns it off.
        cosine_lr (bool): decay the learning rate along a cosine. Defaults to ``False``.
        ema (ExponentialMovingAverage, optional): updated after each step (the caller
            copies it into the model).
        checkpoints (UpdateCheckpoints, optional): makes the loop resumable
            (:func:`~torchrl_dual.objectives.run_updates`).

    Returns:
        dict[str, float]: the last ``log_every`` window's averages, ``loss_diffusion``
        and ``x0_error``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(2, 1, 3), hidden=16, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 2), torch.randn(64, 1))  # offline data
        >>> windows = lambda: TensorDict(observation=torch.randn(8, 4, 2),
        ...                              action=torch.randn(8, 4, 1), batch_size=[8, 4])
        >>> stats = train_planner(model, windows, 5, lr=1e-3, progress=False)
        >>> sorted(stats)
        ['loss_diffusion', 'x0_error']
    """
    loss = DiffusionPlannerLoss(model, action_condition_prob=action_condition_prob)
    optimizer = adam(loss.parameters(), lr=lr)
    kwargs.setdefault("desc", "planner")
    return run_updates(loss, sample, num_updates, optimizer, **kwargs)
