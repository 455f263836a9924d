"""Figures from results: each function draws on a given matplotlib ``ax`` and returns it."""

from __future__ import annotations

import numpy as np

from .common import atomic_save, to_numpy

__all__ = [
    "plot_cloud",
    "plot_curves",
    "plot_trajectories",
    "plot_window",
    "plot_point_particle",
    "plot_relevance",
    "save_figure",
]


def plot_cloud(ax, samples, *, label: str, color: str, alpha: float = 0.3):
    """Scatter of 2-D samples ``(S, 2)``."""
    s = to_numpy(samples)
    ax.scatter(s[:, 0], s[:, 1], s=4, alpha=alpha, color=color, label=label)
    return ax


def plot_curves(
    ax, curves: dict, *, xlabel: str = "iteration", ylabel: str = "", logy: bool = False
):
    """One line per entry of ``{label: (I,) values}``."""
    for label, y in curves.items():
        ax.plot(to_numpy(y), label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
    ax.legend(fontsize=7)
    return ax


def plot_trajectories(
    ax, trajs, *, color: str, label: str | None = None, lw: float = 1.0, alpha: float = 1.0
):
    """Lines of 2-D trajectories ``(n, T, 2)`` (or one ``(T, 2)``)."""
    t = to_numpy(trajs)
    if t.ndim == 2:
        t = t[None]
    for i, tr in enumerate(t):
        ax.plot(
            tr[:, 0], tr[:, 1], color=color, lw=lw, alpha=alpha, label=label if i == 0 else None
        )
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
    ax.set_xlabel("x (unit square)")
    ax.set_ylabel("y (unit square)")
    return ax


def plot_point_particle(ax, task, env):
    """Wall rectangles, hole centre, start (green x) and goal (red x) of one point-particle
    environment ``env (E,)`` in the workspace ``[0, 10]^2``, each labelled for a legend."""
    from matplotlib.patches import Rectangle

    rects = to_numpy(task.wall_rectangles(env))  # (2, 4) x_min, x_max, y_min, y_max
    for x0, x1, y0, y1 in rects:
        if y1 > y0:
            ax.add_patch(
                Rectangle(
                    (x0, y0),
                    x1 - x0,
                    y1 - y0,
                    facecolor="0.65",
                    edgecolor="0.2",
                    lw=1,
                    label="wall",
                )
            )
    e = to_numpy(task.full_env(env))  # (6,)
    ax.plot(e[2], e[3], "+", color="0.2", ms=8, label="hole centre")
    ax.plot(e[0], e[1], "gx", ms=9, mew=2, label="start")
    ax.plot(e[4], e[5], "rx", ms=9, mew=2, label="goal")
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("x (workspace units)", fontsize=7)
    ax.set_ylabel("y (workspace units)", fontsize=7)
    return ax


def plot_relevance(
    ax, relevance, names, *, title: str = "", xlabel: str = "weight index", legend_loc: str = "best"
):
    """Relevance profiles ``(O, N)`` over the weight index (pass a slice, e.g. one DoF's ``K``
    weights ``relevance[:, :K]``, to plot those only). The legend goes to ``legend_loc``
    (``"below"``: under the axes, covering nothing)."""
    r = to_numpy(relevance)
    for o, name in enumerate(names):
        ax.plot(np.arange(r.shape[1]), r[o], marker="o", ms=3, label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("relevance (normalised |Pearson r|)")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xticks(np.arange(r.shape[1]))
    ax.set_title(title)
    if legend_loc == "below":
        ax.legend(
            fontsize=7,
            loc="upper center",
            bbox_to_anchor=(0.5, -0.2),
            ncol=len(names),
            frameon=False,
        )
    else:
        ax.legend(fontsize=7, loc=legend_loc)
    return ax


def save_figure(fig, path) -> None:
    """Save a PNG atomically (mode 0644) and close the figure."""
    import matplotlib.pyplot as plt

    atomic_save(
        path, ".png", lambda tmp: fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    )
    plt.close(fig)
