"""Learning-curve plot of a run's evaluation history."""

from __future__ import annotations

from pathlib import Path


def plot_learning_curve(history: list[dict], path: Path, *, title: str = "") -> Path | None:
    """Normalized score against online frames; the offline score is the point at 0.

    Returns the PNG path, or ``None`` (with a note) when matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            "[dual] matplotlib is not installed: no learning-curve PNG "
            "(pip install 'torchrl-dual[plots]')."
        )
        return None
    frames = [h["frames"] for h in history]
    scores = [h["normalized_score"] for h in history]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(frames, scores, marker="o")
    ax.axvline(0, color="grey", linestyle=":", label="offline → online")
    ax.set_xlabel("online environment frames")
    ax.set_ylabel("normalized score")
    ax.set_title(title)
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
