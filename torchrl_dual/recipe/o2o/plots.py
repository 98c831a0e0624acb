"""The end-of-run plot: the learning curve and the online signals DUAL acts on.

The top panel is the normalized score against online frames (the offline score at 0).
Below it, one panel per online signal the learner reports for each collected batch
(:meth:`~torchrl_dual.recipe.Learner.batch_metrics`), averaged over the batch: the
epistemic standard deviation ``σ_θ(s)`` of the Laplace ensemble policy (the square root
of the variance of Eq. 9 over sub-policies drawn from the posterior of Eq. 8) and DUAL's
shift distance ``d_t = |p̂(s'|s, a) - s'|`` between the transition model's prediction
and the observed next state, which widens the exploration noise of Eq. 10. Algorithms that
report neither (``iql``, ``calql``, ...) get the score panel only.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the file-only backend)

ONLINE_SIGNALS: dict[str, str] = {
    "epistemic_std": "epistemic std",
    "epistemic_share": "epistemic share",  # of the executed variance (exploration_signals)
    "shift_distance": "shift distance $d_t$",
    "exploration_std": "executed action std",
}
"""Per-batch metrics of the online phase that the plot draws (key: panel label)."""
RECORDED_ONLY: tuple[str, ...] = ("reward_per_step",)
"""Per-batch metrics kept with the signals but not drawn: the collected reward (whether
exploration found any, ``benchmarks/studies/online_reward.py``)."""


def online_signals(frames: int, metrics: dict) -> dict | None:
    """The online-signal metrics of one collected batch, with the online frames at its end.

    The :data:`ONLINE_SIGNALS` and :data:`RECORDED_ONLY` metrics among the batch's
    ``metrics``; ``None`` when there are none.

    Examples:
        >>> online_signals(200, {"reward_per_step": 0.1, "shift_distance": 0.5, "loss": 2.0})
        {'frames': 200, 'shift_distance': 0.5, 'reward_per_step': 0.1}
        >>> online_signals(200, {"loss": 2.0}) is None
        True
    """
    names = (*ONLINE_SIGNALS, *RECORDED_ONLY)
    signals = {name: float(metrics[name]) for name in names if name in metrics}
    return {"frames": int(frames), **signals} if signals else None


def plot_learning_curve(
    history: list[dict], path: Path, *, title: str = "", signals: list[dict] | None = None
) -> Path:
    r"""Plots the learning curve and the online signals below it; returns ``path``.

    The normalized score against online frames (the offline score is the point at 0)
    and, below it on the same frame axis, each :data:`ONLINE_SIGNALS` series found in
    ``signals`` (records of :func:`online_signals`).

    Args:
        history (list of dict): the evaluations, each with ``frames`` and
            ``normalized_score`` (``O2ORun.history``).
        path (Path): the image file to write (a ``.png``).

    Keyword Args:
        title (str): the figure's title.
        signals (list of dict, optional): :func:`online_signals` records, one per
            collected batch.

    Returns:
        Path: ``path``.

    Examples:
        >>> import tempfile
        >>> history = [{"frames": 0, "normalized_score": 10.0}, {"frames": 100, "normalized_score": 30.0}]
        >>> signals = [{"frames": 50, "epistemic_std": 0.2}, {"frames": 100, "epistemic_std": 0.1}]
        >>> png = plot_learning_curve(history, Path(tempfile.mkdtemp()) / "c.png", signals=signals)
        >>> png.read_bytes()[:4]
        b'\x89PNG'
    """
    signals = signals or []
    panels = [name for name in ONLINE_SIGNALS if any(name in s for s in signals)]
    fig, axes = plt.subplots(
        1 + len(panels),
        1,
        figsize=(6, 4 + 2 * len(panels)),
        sharex=True,
        squeeze=False,
        gridspec_kw={"height_ratios": [2] + [1] * len(panels)},
    )
    score = axes[0, 0]
    score.plot([h["frames"] for h in history], [h["normalized_score"] for h in history], "o-")
    score.set_ylabel("normalized score")
    score.set_title(title)
    for ax in axes[:, 0]:
        ax.axvline(0, color="grey", linestyle=":", label="offline → online")
        ax.grid(alpha=0.3)
    score.legend(loc="best")
    for ax, name in zip(axes[1:, 0], panels, strict=True):
        series = [s for s in signals if name in s]
        ax.plot([s["frames"] for s in series], [s[name] for s in series], ".-", color="C1")
        ax.set_ylabel(ONLINE_SIGNALS[name])
    axes[-1, 0].set_xlabel("online environment frames")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
