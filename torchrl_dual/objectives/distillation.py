"""Progressive distillation of a trajectory sampler (Salimans & Ho, 2022): loss and driver."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams

from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.objectives._trajectory_window_loss import TrajectoryWindowLoss, masked_mean
from torchrl_dual.objectives.optim import adam
from torchrl_dual.objectives.update_loop import (
    ExponentialMovingAverage,
    UpdateCheckpoints,
    run_updates,
)


class DistillationLoss(TrajectoryWindowLoss):
    """One round of progressive distillation: one student step = two teacher steps.

    DUAL distils the ``N = 32``-step planner into a one-step sampler by halving
    rounds (Section 3.1, "Progressive distillation for fast-sampling";
    Algorithm 1, line 5). For a student with ``K = N_teacher / 2`` steps:

    1. draw a window ``x`` and a grid time ``t = i / K`` (``i ∈ {1..K}``), set
       ``s = t − 1/K`` and ``z_t = α_t·x + σ_t·ε`` (known entries kept clean);
    2. run two deterministic DDIM steps of the frozen teacher,
       ``z_t → z_{t − 1/2K} → z_s``;
    3. the student's target is the ``x̃`` that takes ``z_t`` to ``z_s`` in ONE DDIM
       step: ``x̃ = (z_s − (σ_s/σ_t)·z_t) / (α_s − (σ_s/σ_t)·α_t)``, which is the
       teacher's own ``x̂`` when ``s = 0``;
    4. the loss is ``max(SNR(t), 1)·‖x̂_student − x̃‖²`` ("truncated SNR" weighting),
       averaged over the entries that are not known.

    Args:
        student (TrajectoryDiffusion): trainable, ``num_steps == teacher.num_steps // 2``;
            initialise it from the teacher (see :func:`progressive_distillation`).
        teacher (TrajectoryDiffusion): frozen; receives no gradient.

    Keyword Args:
        action_condition_prob (float): probability that ``a_0`` is known, as in
            :class:`DiffusionPlannerLoss`, so the distilled transition model is
            distilled too. Defaults to ``0.5``.
        reduction (str): ``"none"`` | ``"mean"`` | ``"sum"``. Defaults to ``"mean"``.

    Examples:
        >>> import copy, torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> layout = TrajectoryLayout(obs_dim=3, action_dim=2, horizon=4)
        >>> teacher = TrajectoryDiffusion(layout, num_steps=4, hidden=32, depth=1)
        >>> _ = teacher.normalizer.fit(torch.randn(64, 3), torch.randn(64, 2))  # offline data
        >>> student = copy.deepcopy(teacher)
        >>> student.num_steps = 2
        >>> loss_fn = DistillationLoss(student, teacher)
        >>> windows = TensorDict(
        ...     {"observation": torch.randn(8, 5, 3), "action": torch.randn(8, 5, 2)},
        ...     batch_size=[8, 5],
        ... )
        >>> loss_fn(windows)["loss_distillation"].backward()
    """

    out_keys = ["loss_distillation", "target_gap"]

    student: TrajectoryDiffusion
    student_params: TensorDictParams
    target_student_params: TensorDictParams
    teacher: TrajectoryDiffusion

    def __init__(
        self,
        student: TrajectoryDiffusion,
        teacher: TrajectoryDiffusion,
        *,
        action_condition_prob: float = 0.5,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        if student is teacher:
            raise ValueError("student and teacher must be distinct modules (deepcopy the teacher).")
        if teacher.num_steps != 2 * student.num_steps:
            raise ValueError(
                f"A student takes half its teacher's steps: teacher has {teacher.num_steps}, "
                f"student {student.num_steps}; set student.num_steps = {teacher.num_steps // 2}."
            )
        self.convert_to_functional(student, "student")
        # The teacher is frozen: a private copy whose weights are buffers, never parameters
        # (the caller's teacher is neither modified nor reset by reset_parameters_recursive);
        # a cast or device move of the loss carries it, and it runs without a weight swap.
        self.teacher = _frozen_copy(teacher)
        self.action_condition_prob = action_condition_prob
        self.reduction = reduction

    def reset_parameters_recursive(self) -> None:
        """Re-initialises the student only; the teacher is a frozen reference."""
        self._reset_module_parameters("student", self.student)

    @torch.no_grad()
    def teacher_target(
        self, z: torch.Tensor, i: torch.Tensor, cond: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """The student's ``x̃`` for ``z`` at grid index ``i`` (two teacher DDIM steps)."""
        steps = self.student.num_steps
        t, mid, s = i / steps, (i - 0.5) / steps, (i - 1) / steps
        teacher = self.teacher
        z_mid = teacher.ddim_step(z, t, mid, cond, mask)
        z_s = teacher.ddim_step(z_mid, mid, s, cond, mask)
        alpha_t, sigma_t = teacher._scales(t, z)
        alpha_s, sigma_s = teacher._scales(s, z)
        ratio = sigma_s / sigma_t
        return torch.where(mask, cond, (z_s - ratio * z) / (alpha_s - ratio * alpha_t))

    def distillation_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Per-window truncated-SNR weighted x-error against the two-step target."""
        student = self.student
        with self.student_params.to_module(student):  # the normalizer's statistics too
            x0, mask = self._windows(student, tensordict)
            batch = x0.shape[:-2]
            i = torch.randint(1, student.num_steps + 1, batch, device=x0.device).to(x0.dtype)
            t = i / student.num_steps
            z = torch.where(mask, x0, student.noise(x0, t, torch.randn_like(x0)))
            target = self.teacher_target(z, i, x0, mask)
            x_hat = student.predict(z, t, x0, mask)[0]
        weight = student.schedule.snr(t).clamp(min=1.0, max=1e4)[..., None, None]
        loss = masked_mean(weight * (x_hat - target) ** 2, mask)
        metadata = {"target_gap": masked_mean((x_hat - target) ** 2, mask).mean().detach()}
        return loss, metadata

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """The reduced distillation loss and its diagnostics.

        Args:
            tensordict (TensorDictBase): a batch of windows (see the class docstring for its keys).

        Returns:
            ``loss_distillation`` and the metrics :meth:`distillation_loss` returns.
        """
        loss, metadata = self.distillation_loss(tensordict)
        loss = self._reduce_loss(loss)
        return TensorDict({"loss_distillation": loss, **metadata}, batch_size=[])


def _frozen_copy(module: torch.nn.Module) -> torch.nn.Module:
    """A deep copy of ``module`` with its parameters as buffers (never trained or reset)."""
    frozen = copy.deepcopy(module)
    for part in frozen.modules():
        for name, param in list(part.named_parameters(recurse=False)):
            delattr(part, name)
            part.register_buffer(name, param.detach())
    return frozen


class _RoundCheckpoints:
    """One round's view of :func:`progressive_distillation`'s checkpoints.

    Its loop state is saved under the round's index, its updates counted over all
    rounds. Only the round a resumed distillation continues asks ``outer`` to resume
    (right before its loop runs, where the caller may restore its random state).
    """

    def __init__(
        self, outer: UpdateCheckpoints, index: int, updates: Sequence[int], resuming: bool
    ) -> None:
        self.outer, self.index, self.resuming = outer, index, resuming
        self.offset, self.total = sum(updates[:index]), sum(updates)

    def resume(self) -> dict[str, Any] | None:
        saved = self.outer.resume() if self.resuming else None
        return None if saved is None else saved["loop"]

    def after_update(self, done: int, total: int, state: Callable[[], dict[str, Any]]) -> None:
        self.outer.after_update(
            self.offset + done, self.total, lambda: {"round": self.index, "loop": state()}
        )


def progressive_distillation(
    teacher: TrajectoryDiffusion,
    sample: Callable[[], TensorDictBase],
    updates_per_round: int | Sequence[int],
    *,
    final_steps: int = 1,
    lr: float = 1e-4,
    action_condition_prob: float = 0.5,
    ema_decay: float | None = 0.995,
    logger=None,
    progress: bool = True,
    checkpoints: UpdateCheckpoints | None = None,
    **kwargs,
) -> TrajectoryDiffusion:
    """Halves the sampler's steps until ``final_steps`` (Algorithm 1, line 5).

    Each round deep-copies its teacher into the student, halves ``num_steps`` and
    minimises :class:`DistillationLoss`; the student becomes the next teacher.
    ``N = 32`` to ``1`` takes five rounds: 32 → 16 → 8 → 4 → 2 → 1. The last rounds are
    the hardest (a one-step map must split modes sharply), so ``updates_per_round`` may
    be a sequence, one entry per round, that spends more updates there. Within a round
    the learning rate decays along a cosine and the student kept at the end is the
    exponential moving average of its weights (``ema_decay``; ``None`` keeps the last).

    With ``checkpoints`` (:class:`~torchrl_dual.objectives.UpdateCheckpoints`) the rounds
    are checkpointed within: a resumed distillation skips the finished rounds (their
    students' weights come back with the round it continues) and continues that round's
    loop; ``done`` counts the updates of all rounds.

    Args:
        teacher (TrajectoryDiffusion): the trained ``N``-step planner (Algorithm 1,
            lines 3-4), its normalizer fitted.
        sample (callable): ``() -> TensorDict`` of windows ``[B, H + 1]`` with the
            observation ``[B, H + 1, obs_dim]`` and the action ``[B, H + 1, action_dim]``,
            called once per update (as for :func:`train_planner`).
        updates_per_round (int or sequence of int): updates of each round, or one entry
            per round (``log2(N / final_steps)`` of them).

    Keyword Args:
        final_steps (int): the student's sampling steps at the end, ``N / 2^k``.
            Defaults to ``1`` (DUAL's one-step actor).
        lr (float): Adam's initial learning rate in each round (decayed along a cosine).
            Defaults to ``1e-4``.
        action_condition_prob (float): probability that ``a_0`` is given too
            (:class:`DistillationLoss`), so the student stays a transition model.
            Defaults to ``0.5``.
        ema_decay (float, optional): decay of the weights' moving average kept at the
            end of each round. Defaults to ``0.995``; ``None`` keeps the last weights.
        logger (Logger, optional): a TorchRL logger; each round logs its averages as
            ``distill_{n}/{name}`` (``n`` the student's steps).
        progress (bool): show a tqdm progress bar per round. Defaults to ``True``.
        checkpoints (UpdateCheckpoints, optional): makes the rounds resumable (see above).
        **kwargs: passed to :func:`~torchrl_dual.objectives.run_updates`: ``grad_clip``
            (default ``1.0``), ``log_every`` (``100``), ``step_offset`` (``0``).

    Returns:
        TrajectoryDiffusion: the final student (the input ``teacher`` is left unchanged).

    Raises:
        ValueError: ``final_steps`` is not ``N / 2^k``, or ``updates_per_round`` has
            another number of entries than there are rounds.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> layout = TrajectoryLayout(obs_dim=2, action_dim=1, horizon=3)
        >>> teacher = TrajectoryDiffusion(layout, num_steps=4, hidden=16, depth=1)
        >>> _ = teacher.normalizer.fit(torch.randn(64, 2), torch.randn(64, 1))
        >>> windows = lambda: TensorDict(observation=torch.randn(8, 4, 2),
        ...                              action=torch.randn(8, 4, 1), batch_size=[8, 4])
        >>> student = progressive_distillation(teacher, windows, [2, 3], progress=False)
        >>> student.num_steps, teacher.num_steps  # two rounds: 4 -> 2 -> 1
        (1, 4)
    """
    steps = teacher.num_steps
    if (
        final_steps < 1
        or steps % final_steps
        or (steps // final_steps) & (steps // final_steps - 1)
    ):
        raise ValueError(f"final_steps={final_steps} must be N / 2^k for the teacher's N={steps}.")
    num_rounds = (steps // final_steps).bit_length() - 1
    if isinstance(updates_per_round, int):
        updates_per_round = [updates_per_round] * num_rounds
    if len(updates_per_round) != num_rounds:
        raise ValueError(
            f"updates_per_round has {len(updates_per_round)} entries but distilling "
            f"{steps} -> {final_steps} steps takes {num_rounds} rounds."
        )
    saved = None if checkpoints is None else checkpoints.resume()
    first = 0 if saved is None else saved["round"]
    current = teacher
    for index, round_updates in enumerate(updates_per_round):
        student = copy.deepcopy(current)
        student.num_steps = current.num_steps // 2
        if index < first:  # done before the resume: round `first` loads its weights
            current = student
            continue
        loss = DistillationLoss(student, current, action_condition_prob=action_condition_prob)
        optimizer = adam(loss.parameters(), lr=lr)
        ema = None if ema_decay is None else ExponentialMovingAverage(student, ema_decay)
        run_updates(
            loss,
            sample,
            round_updates,
            optimizer,
            desc=f"distil {current.num_steps}->{student.num_steps}",
            logger=logger,
            log_prefix=f"distill_{student.num_steps}/",
            progress=progress,
            cosine_lr=True,
            ema=ema,
            checkpoints=None
            if checkpoints is None
            else _RoundCheckpoints(
                checkpoints, index, updates_per_round, saved is not None and index == first
            ),
            **kwargs,
        )
        if ema is not None:
            ema.copy_to(student)
        current = student
    return current
