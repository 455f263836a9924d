"""Figures of one online episode of the point-particle task (the paper's Fig. 6).

Each function takes the episode as arrays (see
:meth:`protorch.control.particle.EpisodeResult.episode`,
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
    positions, envs, means, markers = (
        to_numpy(positions),
        to_numpy(envs),
        to_numpy(means),
        to_numpy(markers),
    )
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise ValueError(f"positions must be (T+1, 2), got shape {positions.shape}")
    n = positions.shape[0]
    if envs.ndim != 2 or envs.shape != (n, 6):
        raise ValueError(
            f"envs must be (T+1, 6) = ({n}, 6) full environments, got shape {envs.shape}"
        )
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


class _EpisodeArtists:
    """The artists of an episode frame on ``ax`` (the wall, its hole, start, goal and its circle,
    the mean, the path earlier (faded) and now, the particle and the marker), created once and
    moved to instant ``t`` by :meth:`show`, so an animation redraws only what moves (see
    :func:`write_episode_gif`)."""

    def __init__(
        self, ax, positions, envs, means, markers, *, goal_tol: float, legend: bool, recent, dt
    ):
        from matplotlib.patches import Circle, Rectangle

        self.ax, self.positions, self.envs, self.means, self.markers = (
            ax,
            positions,
            envs,
            means,
            markers,
        )
        self.recent = max(1, int(round(recent / dt)))  # seconds -> steps
        self.walls = [
            ax.add_patch(
                Rectangle(
                    (0, 0),
                    2 * _WALL_HALF_WIDTH,
                    0,
                    facecolor="0.6",
                    edgecolor="0.2",
                    lw=1,
                    zorder=1,
                    label=label,
                )
            )
            for label in ("wall (now)", "_")
        ]
        (self.hole,) = ax.plot([], [], "+", color="0.2", ms=8, zorder=2, label="hole centre")
        self.ring = ax.add_patch(
            Circle(
                (0, 0),
                goal_tol,
                fill=False,
                edgecolor="r",
                ls=":",
                lw=1,
                zorder=2,
                label="goal tolerance",
            )
        )
        (self.start,) = ax.plot([], [], "x", color="g", ms=9, mew=2, zorder=3, label="start")
        (self.goal,) = ax.plot([], [], "x", color="r", ms=9, mew=2, zorder=3, label="goal")
        (self.mean,) = ax.plot([], [], "-", color="tab:red", lw=1.2, zorder=4, label="ProMP mean")
        (self.earlier,) = ax.plot(
            [],
            [],
            "-",
            color="tab:blue",
            lw=1.0,
            alpha=0.3,
            zorder=5,
            label="path earlier, faded: the wall has moved since",
        )
        (self.path,) = ax.plot([], [], "-", color="tab:blue", lw=1.5, zorder=5, label="path")
        (self.particle,) = ax.plot([], [], "o", color="m", ms=7, zorder=6, label="particle")
        self.marker = (
            None
            if markers is None
            else ax.plot([], [], "*", color="k", ms=9, zorder=7, label="marker")[0]
        )
        lo, hi = _LIMITS
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (workspace units)", fontsize=7)
        ax.set_ylabel("y (workspace units)", fontsize=7)
        if legend:  # outside the axes, on the right: the wall and the goal can be anywhere inside
            ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)

    @property
    def moving(self) -> list:
        """The artists :meth:`show` changes, in drawing order (the axes' title last)."""
        arts = [
            *self.walls,
            self.hole,
            self.ring,
            self.start,
            self.goal,
            self.mean,
            self.earlier,
            self.path,
            self.particle,
        ]
        return arts + ([] if self.marker is None else [self.marker]) + [self.ax.title]

    def show(self, t: int, title: str) -> None:
        """Move every artist to instant ``t`` and set the axes' title."""
        sx, sy, wx, hy, gx, gy = self.envs[t]
        lo, hi = _LIMITS
        for rect, (y_lo, y_hi) in zip(
            self.walls, ((lo, hy - _HOLE_HALF_HEIGHT), (hy + _HOLE_HALF_HEIGHT, hi))
        ):
            rect.set_xy((wx - _WALL_HALF_WIDTH, y_lo))
            rect.set_height(max(y_hi - y_lo, 0.0))
            rect.set_visible(bool(y_hi > y_lo))
        self.hole.set_data([wx], [hy])
        self.ring.set_center((gx, gy))
        self.start.set_data([sx], [sy])
        self.goal.set_data([gx], [gy])
        self.mean.set_data(self.means[t, :, 0], self.means[t, :, 1])
        split = past_path_split(self.envs, t, self.recent)
        self.earlier.set_data(self.positions[: split + 1, 0], self.positions[: split + 1, 1])
        self.earlier.set_visible(split > 0)  # only once the wall has moved
        self.path.set_data(self.positions[split : t + 1, 0], self.positions[split : t + 1, 1])
        self.particle.set_data([self.positions[t, 0]], [self.positions[t, 1]])
        if self.marker is not None:
            self.marker.set_data([self.markers[t, 0]], [self.markers[t, 1]])
        self.ax.set_title(title, fontsize=9)


def draw_online_frame(
    ax,
    positions,
    envs,
    means,
    markers=None,
    *,
    t: int,
    dt: float = 0.01,
    goal_tol: float = 0.2,
    legend: bool = False,
    recent: float = 0.1,
):
    """Draw instant ``t`` of an episode on ``ax``: the wall (grey) with its hole, start (green x),
    goal (red x) with its ``goal_tol`` circle, the particle's path so far (blue) and position,
    the current ProMP mean (red) and marker (black star). The wall is drawn where it is at ``t``;
    the path from before the wall last moved, older than ``recent`` seconds, is faded (it passed
    the wall where the wall was then, :func:`past_path_split`). Returns ``ax``."""
    positions, envs, means, markers = _check(positions, envs, means, markers)
    if not 0 <= t < positions.shape[0]:
        raise ValueError(f"t must be in [0, {positions.shape[0] - 1}], got {t}")
    arts = _EpisodeArtists(
        ax, positions, envs, means, markers, goal_tol=goal_tol, legend=False, recent=recent, dt=dt
    )
    arts.show(t, f"t = {t * dt:.2f} s")
    for a in arts.moving:
        if not a.get_visible():
            a.remove()  # an empty wall rectangle, the faded path before the wall first moved
    if legend:  # outside the axes, on the right: the wall and the goal can be anywhere inside
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    return ax


def plot_episode_frames(
    path,
    positions,
    envs,
    means,
    markers=None,
    *,
    dt: float = 0.01,
    frames=None,
    num_frames: int = 5,
    success: bool | None = None,
    title: str | None = None,
    goal_tol: float = 0.2,
    dpi: int = 110,
) -> Path:
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
    return atomic_save(
        path, ".png", lambda tmp: fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    )


def write_episode_gif(
    path,
    positions,
    envs,
    means,
    markers=None,
    *,
    dt: float = 0.01,
    fps: int = 20,
    max_frames: int = 60,
    success: bool | None = None,
    title: str | None = None,
    goal_tol: float = 0.2,
    dpi: int = 80,
) -> Path:
    """An animated GIF of one episode at ``path`` (written with Pillow); returns the path.

    At most ``max_frames`` instants, evenly spaced and always including the last. What does not
    move (axes, ticks, labels, legend) is drawn once; each frame restores that background and
    draws only the moving artists on it, a tenth of the time of a full redraw per frame.
    """
    from PIL import Image

    positions, envs, means, markers = _check(positions, envs, means, markers)
    if int(fps) < 1 or int(max_frames) < 1:
        raise ValueError(f"fps and max_frames must be >= 1, got {fps}, {max_frames}")
    idx = frame_indices(positions.shape[0], None, int(max_frames))
    fig = new_figure((5.4, 4))
    fig.set_dpi(dpi)
    ax = fig.add_axes((0.1, 0.11, 0.62, 0.8))  # room on the right for the legend
    head = title or "online episode"
    if success is not None:
        head += f": {'success' if success else 'failure'}"
    arts = _EpisodeArtists(
        ax, positions, envs, means, markers, goal_tol=goal_tol, legend=True, recent=0.1, dt=dt
    )  # draw_online_frame's faded path
    arts.show(idx[0], head)  # the legend and the layout see every artist once
    for a in arts.moving:
        a.set_animated(True)  # left out of the background
    canvas = fig.canvas
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    frames: list[Image.Image] = []
    for t in idx:
        canvas.restore_region(background)
        arts.show(t, f"{head}, t = {t * dt:.2f} s")
        for a in arts.moving:
            ax.draw_artist(a)
        frame = Image.frombuffer(
            "RGBA", canvas.get_width_height(), bytes(canvas.buffer_rgba())
        ).convert("RGB")
        # one palette for every frame, from the first (its legend shows every colour): mapping a
        # frame to it is a fifth of the time of Pillow's own palette per frame
        frames.append(
            frame.quantize(colors=255, method=Image.Quantize.FASTOCTREE)
            if not frames
            else frame.quantize(palette=frames[0], dither=Image.Dither.NONE)
        )
    return atomic_save(
        path,
        ".gif",
        lambda tmp: frames[0].save(
            tmp,
            format="GIF",
            save_all=True,
            append_images=frames[1:],
            duration=int(1000 / int(fps)),
            loop=0,
        ),
    )
