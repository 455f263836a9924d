"""Figures of one online episode of the point-particle task (the paper's Fig. 6).

Each function takes the episode as arrays (see :meth:`protorch.control.particle.EpisodeResult.episode`,
whose dict can be passed as ``**kwargs``), writes one file atomically (temporary file in the same
folder, then ``os.replace``) and returns its path. Figures are drawn on their own Agg canvas
(no pyplot), so the caller's backend and figures are untouched.

Arrays (numpy or torch, ``T + 1`` instants ``t dt``):
``positions (T+1, 2)`` the particle, ``envs (T+1, 6)`` the full 6-D environment
``(start_x, start_y, wall_x, hole_y, goal_x, goal_y)`` at each instant, ``means (T+1, P, 2)`` the
ProMP mean trajectory predicted at each instant, ``markers (T+1, 2)`` the tracked point (optional).
"""

from __future__ import annotations

from pathlib import Path

from .common import atomic_save, frame_indices, legend_below, new_figure, to_numpy

__all__ = ["draw_online_frame", "past_path_split", "plot_episode_frames", "write_episode_gif"]

_WALL_HALF_WIDTH = 1.0  # as protorch.tasks.point_particle
_HOLE_HALF_HEIGHT = 1.0
_LIMITS = (0.0, 10.0)


def _check(positions, envs, means, markers):
    positions, envs, means, markers = to_numpy(positions), to_numpy(envs), to_numpy(means), to_numpy(markers)
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise ValueError(f"positions must be (T+1, 2), got shape {positions.shape}")
    n = positions.shape[0]
    if envs.ndim != 2 or envs.shape != (n, 6):
        raise ValueError(f"envs must be (T+1, 6) = ({n}, 6) full environments, got shape {envs.shape}")
    if means.ndim != 3 or means.shape[0] != n or means.shape[2] != 2:
        raise ValueError(f"means must be (T+1, P, 2) with T+1 = {n}, got shape {means.shape}")
    if markers is not None and markers.shape != (n, 2):
        raise ValueError(f"markers must be (T+1, 2) = ({n}, 2), got shape {markers.shape}")
    return positions, envs, means, markers


def past_path_split(envs, t: int, recent: int) -> int:
    """The first instant of the path drawn solid at ``t``: the last ``recent`` steps, and any
    earlier ones while the environment (the wall, its hole) stood where it stands at ``t``; the
    path before it was drawn next to a wall that has moved since, so it is drawn faded."""
    start = max(0, t - recent)
    while start > 0 and (envs[start - 1, 2:4] == envs[t, 2:4]).all():
        start -= 1
    return start


def draw_online_frame(ax, positions, envs, means, markers=None, *, t: int, dt: float = 0.01,
                      goal_tol: float = 0.2, legend: bool = False, recent: float = 0.1):
    """Draw instant ``t`` of an episode on ``ax``: the wall (grey) with its hole, start (green x),
    goal (red x) with its ``goal_tol`` circle, the particle's path so far (blue) and position,
    the current ProMP mean (red) and marker (black star). The wall is drawn where it is at ``t``;
    the path from before the wall last moved, older than ``recent`` seconds, is faded (it passed
    the wall where the wall was then, :func:`past_path_split`). Returns ``ax``."""
    from matplotlib.patches import Circle, Rectangle

    positions, envs, means, markers = _check(positions, envs, means, markers)
    if not 0 <= t < positions.shape[0]:
        raise ValueError(f"t must be in [0, {positions.shape[0] - 1}], got {t}")
    sx, sy, wx, hy, gx, gy = envs[t]
    lo, hi = _LIMITS
    x0, w = wx - _WALL_HALF_WIDTH, 2 * _WALL_HALF_WIDTH
    for y_lo, y_hi in ((lo, hy - _HOLE_HALF_HEIGHT), (hy + _HOLE_HALF_HEIGHT, hi)):
        if y_hi > y_lo:
            ax.add_patch(Rectangle((x0, y_lo), w, y_hi - y_lo, facecolor="0.6", edgecolor="0.2",
                                   lw=1, zorder=1, label="wall (now)"))
    ax.plot([wx], [hy], "+", color="0.2", ms=8, zorder=2, label="hole centre")
    ax.add_patch(Circle((gx, gy), goal_tol, fill=False, edgecolor="r", ls=":", lw=1, zorder=2,
                        label="goal tolerance"))
    ax.plot(sx, sy, "x", color="g", ms=9, mew=2, zorder=3, label="start")
    ax.plot(gx, gy, "x", color="r", ms=9, mew=2, zorder=3, label="goal")
    ax.plot(means[t, :, 0], means[t, :, 1], "-", color="tab:red", lw=1.2, zorder=4, label="ProMP mean")
    split = past_path_split(envs, t, max(1, int(round(recent / dt))))
    if split > 0:  # before the wall moved to where it is now
        ax.plot(positions[: split + 1, 0], positions[: split + 1, 1], "-", color="tab:blue", lw=1.0, alpha=0.3,
                zorder=5, label="path earlier, faded: the wall has moved since")
    ax.plot(positions[split: t + 1, 0], positions[split: t + 1, 1], "-", color="tab:blue", lw=1.5, zorder=5,
            label="path")
    ax.plot(positions[t, 0], positions[t, 1], "o", color="m", ms=7, zorder=6, label="particle")
    if markers is not None:
        ax.plot(markers[t, 0], markers[t, 1], "*", color="k", ms=9, zorder=7, label="marker")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_aspect("equal")
    ax.set_title(f"t = {t * dt:.2f} s", fontsize=9)
    ax.tick_params(labelsize=7)
    ax.set_xlabel("x (workspace units)", fontsize=7)
    ax.set_ylabel("y (workspace units)", fontsize=7)
    if legend:  # outside the axes, on the right: the wall and the goal can be anywhere inside
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    return ax


def plot_episode_frames(path, positions, envs, means, markers=None, *, dt: float = 0.01, frames=None,
                        num_frames: int = 5, success: bool | None = None, title: str | None = None,
                        goal_tol: float = 0.2, dpi: int = 110) -> Path:
    """A row of Fig. 6-style frames of one episode, written as a PNG to ``path``; returns it.

    ``frames``: the instants to draw; default ``num_frames`` evenly spaced from the first to the
    last instant. ``success`` (optional) goes into the title.
    """
    positions, envs, means, markers = _check(positions, envs, means, markers)
    idx = frame_indices(positions.shape[0], frames, num_frames)
    fig = new_figure((2.6 * len(idx), 2.9))
    axes = fig.subplots(1, len(idx), squeeze=False)
    for ax, t in zip(axes[0], idx):
        draw_online_frame(ax, positions, envs, means, markers, t=t, dt=dt, goal_tol=goal_tol)
    head = title or "online episode"
    if success is not None:
        head += f": {'success' if success else 'failure'}"
    fig.suptitle(head, fontsize=10)
    fig.tight_layout()
    legend_below(fig, axes)
    return atomic_save(path, ".png", lambda tmp: fig.savefig(tmp, dpi=dpi, format="png",
                                                            bbox_inches="tight"))


def write_episode_gif(path, positions, envs, means, markers=None, *, dt: float = 0.01, fps: int = 20,
                      max_frames: int = 60, success: bool | None = None, title: str | None = None,
                      goal_tol: float = 0.2, dpi: int = 80) -> Path:
    """An animated GIF of one episode (``matplotlib.animation`` + ``PillowWriter``) at ``path``.

    At most ``max_frames`` instants, evenly spaced and always including the last; returns the path.
    """
    from matplotlib.animation import FuncAnimation, PillowWriter

    positions, envs, means, markers = _check(positions, envs, means, markers)
    if int(fps) < 1 or int(max_frames) < 1:
        raise ValueError(f"fps and max_frames must be >= 1, got {fps}, {max_frames}")
    idx = frame_indices(positions.shape[0], None, int(max_frames))
    fig = new_figure((5.4, 4))
    ax = fig.add_axes((0.1, 0.11, 0.62, 0.8))  # room on the right for the legend
    head = title or "online episode"
    if success is not None:
        head += f": {'success' if success else 'failure'}"

    def update(t):
        ax.clear()
        draw_online_frame(ax, positions, envs, means, markers, t=t, dt=dt, goal_tol=goal_tol, legend=True)
        ax.set_title(f"{head}, t = {t * dt:.2f} s", fontsize=9)
        return ()

    anim = FuncAnimation(fig, update, frames=idx, blit=False, repeat=False)
    return atomic_save(path, ".gif", lambda tmp: anim.save(tmp, writer=PillowWriter(fps=int(fps)), dpi=dpi))
