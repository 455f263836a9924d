"""Figures from results: each function draws on a given matplotlib ``ax`` and returns it."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_cloud", "plot_curves", "plot_trajectories", "plot_window", "plot_relevance", "save_figure"]


def _np(x):
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def plot_cloud(ax, samples, *, label: str, color: str, alpha: float = 0.3):
    """Scatter of 2-D samples ``(S, 2)``."""
    s = _np(samples)
    ax.scatter(s[:, 0], s[:, 1], s=4, alpha=alpha, color=color, label=label)
    return ax


def plot_curves(ax, curves: dict, *, xlabel: str = "iteration", ylabel: str = "", logy: bool = False):
    """One line per entry of ``{label: (I,) values}``."""
    for label, y in curves.items():
        ax.plot(_np(y), label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
    ax.legend(fontsize=7)
    return ax


def plot_trajectories(ax, trajs, *, color: str, label: str | None = None, lw: float = 1.0, alpha: float = 1.0):
    """Lines of 2-D trajectories ``(n, T, 2)`` (or one ``(T, 2)``)."""
    t = _np(trajs)
    if t.ndim == 2:
        t = t[None]
    for i, tr in enumerate(t):
        ax.plot(tr[:, 0], tr[:, 1], color=color, lw=lw, alpha=alpha, label=label if i == 0 else None)
    return ax


def plot_window(ax, task):
    """Wall, window, start and end of a :class:`~protorch.tasks.WindowTask`."""
    cx, cy = task.centre
    h = task.window_width / 2
    ax.plot([cx, cx], [0, cy - h], color="k", lw=4)
    ax.plot([cx, cx], [cy + h, 1], color="k", lw=4)
    ax.plot(*task.start, "gx", ms=10, mew=3)
    ax.plot(*task.end, "rx", ms=10, mew=3)
    ax.plot(cx, cy, "b+", ms=10, mew=2)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    return ax


def plot_relevance(ax, relevance, names, *, title: str = ""):
    """Relevance profiles ``(O, N)`` over the weight index."""
    r = _np(relevance)
    for o, name in enumerate(names):
        ax.plot(np.arange(r.shape[1]), r[o], marker="o", ms=3, label=name)
    ax.set_xlabel("weight index")
    ax.set_ylabel("relevance")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(title)
    ax.legend(fontsize=7)
    return ax


def save_figure(fig, path) -> None:
    """Save a PNG atomically and close the figure."""
    import os
    from pathlib import Path

    import matplotlib.pyplot as plt

    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110, bbox_inches="tight")
    os.replace(tmp, path)
    plt.close(fig)
