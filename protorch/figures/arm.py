"""Figures of the arm experiment (the paper's Fig. 7): top views of end-effector paths around the
can, a 3-D view of the arm, frames and a GIF of a moving episode in which the arm switches sides.

Drawing functions take an ``ax`` and return it; the file writers draw on their own Agg canvas (no
pyplot state) and write atomically, like :mod:`protorch.figures.online`. Inputs are numpy arrays or
tensors; an episode is the dict of :meth:`protorch.control.arm.ArmEpisodeResult.episode`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..gp.model import label_aware_mean
from .common import atomic_save, frame_indices, legend_below, new_figure, to_numpy

__all__ = [
    "CLASS_COLORS",
    "draw_can",
    "plot_top_view",
    "plot_arm_3d",
    "draw_episode_frame",
    "plot_switch_frames",
    "write_switch_gif",
    "experiment_figures",
]

CLASS_COLORS = {0: "tab:blue", 1: "tab:orange"}  # LEFT, RIGHT
_NAMES = {0: "left", 1: "right"}


def draw_can(ax, task, env, *, margin: bool = True):
    """The can (filled circle), its radius plus ``task.margin`` (dashed), the start (green x) and
    the target (red x, with its tolerance circle) of ``env (4,)`` in a top view."""
    from matplotlib.patches import Circle

    e = to_numpy(env)
    ax.add_patch(Circle((e[0], e[1]), task.can_radius, facecolor="0.55", edgecolor="0.2", zorder=2))
    if margin:
        ax.add_patch(
            Circle(
                (e[0], e[1]),
                task.can_radius + task.margin,
                fill=False,
                ls="--",
                ec="0.3",
                lw=0.8,
                zorder=2,
            )
        )
    ax.add_patch(Circle((e[2], e[3]), task.goal_tol, fill=False, ec="r", ls=":", lw=1, zorder=2))
    ax.plot(task.start[0], task.start[1], "x", color="g", ms=8, mew=2, zorder=3)
    ax.plot(e[2], e[3], "x", color="r", ms=8, mew=2, zorder=3)
    return ax


def _limits(ax, task):
    (cx0, cx1), (cy0, cy1) = task.can_box
    (gx0, gx1), (gy0, gy1) = task.goal_box
    ax.set_xlim(min(task.start[0], cx0) - 0.08, max(cx1, gx1) + 0.06)
    ax.set_ylim(min(cy0, gy0) - 0.2, max(cy1, gy1) + 0.2)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_xlabel("x [m] (forward)", fontsize=7)
    ax.set_ylabel("y [m] (robot's left)", fontsize=7)


def plot_top_view(ax, task, env, paths: dict, *, title: str | None = None):
    """End-effector paths ``{name: ((T, 3) path, color, style)}`` around the can of ``env (4,)``,
    seen from above (x forward, y to the robot's left)."""
    draw_can(ax, task, env)
    for name, (path, color, style) in paths.items():
        p = to_numpy(path)
        ax.plot(p[:, 0], p[:, 1], style, color=color, lw=1.6, label=name, zorder=4)
    _limits(ax, task)
    if title:
        ax.set_title(title, fontsize=8)
    return ax


def plot_arm_3d(ax, task, q, env, *, instants: int = 7):
    """The arm's skeleton at ``instants`` evenly spaced steps of the joint trajectory ``q (T, 7)``,
    its end-effector path, the can (a cylinder), the table and the target, on a 3-D ``ax``."""
    q = torch.as_tensor(q)
    with torch.no_grad():
        links = to_numpy(task.kinematics.link_positions(q.to(task.kinematics.lower)))  # (T, F, 3)
    e = to_numpy(env)
    # table and can
    (_, tx1), (ty0, ty1) = task.table
    xx, yy = np.meshgrid([-0.1, tx1], [ty0, ty1])  # the table top, the robot's base on it
    ax.plot_surface(xx, yy, np.zeros_like(xx), color="burlywood", alpha=0.25, zorder=0)
    th, zz = np.meshgrid(np.linspace(0, 2 * np.pi, 30), [0.0, task.can_height])
    ax.plot_surface(
        e[0] + task.can_radius * np.cos(th),
        e[1] + task.can_radius * np.sin(th),
        zz,
        color="0.5",
        alpha=0.7,
    )
    cmap = __import__("matplotlib").colormaps["viridis"]
    idx = np.linspace(0, len(links) - 1, instants).round().astype(int)
    for k, i in enumerate(idx):
        c = cmap(k / max(len(idx) - 1, 1))
        ax.plot(links[i, :, 0], links[i, :, 1], links[i, :, 2], "-o", color=c, ms=2.5, lw=2)
    ax.plot(
        links[:, -1, 0],
        links[:, -1, 1],
        links[:, -1, 2],
        "-",
        color="k",
        lw=1.2,
        label="end effector",
    )
    ax.scatter([e[2]], [e[3]], [task.ee_height], color="r", marker="x", s=40)
    ax.set_xlim(-0.1, 0.9)
    ax.set_ylim(-0.45, 0.45)
    ax.set_zlim(0.0, 0.9)
    ax.set_box_aspect((0.9, 0.9, 0.9))
    ax.set_xlabel("x [m]", fontsize=7)
    ax.set_ylabel("y [m]", fontsize=7)
    ax.set_zlabel("z [m]", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.view_init(elev=28, azim=-120)
    return ax


def draw_episode_frame(ax, task, ep: dict, *, t: int, legend: bool = False):
    """Instant ``t`` of a moving episode, from above: can and target of that instant, the arm's
    skeleton (grey), the end-effector path so far (black) and the tracked class's mean path
    (blue: left, orange: right)."""
    envs, links, means, labels, ee = ep["envs"], ep["links"], ep["means"], ep["labels"], ep["ee"]
    if not 0 <= t < len(envs):
        raise ValueError(f"t must be in [0, {len(envs) - 1}], got {t}")
    draw_can(ax, task, envs[t])
    lab = int(labels[t])
    ax.plot(
        means[t, :, 0],
        means[t, :, 1],
        "-",
        color=CLASS_COLORS.get(lab, "m"),
        lw=1.5,
        label=f"tracked mean ({_NAMES.get(lab, lab)})",
        zorder=4,
    )
    ax.plot(links[t, :, 0], links[t, :, 1], "-o", color="0.45", ms=2, lw=2, zorder=5, label="arm")
    ax.plot(ee[: t + 1, 0], ee[: t + 1, 1], "-", color="k", lw=1.3, zorder=6, label="end effector")
    _limits(ax, task)
    ax.set_title(f"t = {t * ep['dt']:.2f} s, {_NAMES.get(lab, lab)}", fontsize=8)
    if legend:  # outside the axes, on the right: the can and the target can be anywhere inside
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    return ax


def _switch_frames(labels, n: int, num_frames: int) -> list[int]:
    """Frames around the first switch: the start, just before and after it, and the end."""
    sw = np.nonzero(labels[1:] != labels[:-1])[0]
    if sw.size == 0:
        return frame_indices(n, None, num_frames)
    t = int(sw[0]) + 1
    picks = {0, max(t - 3, 0), min(t + 8, n - 1), min(t + 25, n - 1), n - 1}
    return sorted(picks)[:num_frames] if len(picks) >= num_frames else sorted(picks)


def plot_switch_frames(
    path,
    task,
    ep: dict,
    *,
    frames=None,
    num_frames: int = 5,
    title: str | None = None,
    dpi: int = 110,
) -> Path:
    """A row of frames of one episode (default: around its first switch) as a PNG; returns the
    path."""
    n = len(ep["envs"])
    idx = (
        _switch_frames(ep["labels"], n, num_frames)
        if frames is None
        else frame_indices(n, frames, num_frames)
    )
    fig = new_figure((2.9 * len(idx), 3.2))
    axes = fig.subplots(1, len(idx), squeeze=False)
    for ax, t in zip(axes[0], idx):
        draw_episode_frame(ax, task, ep, t=t)
    head = title or "moving can / target"
    fig.suptitle(f"{head}: {'success' if ep['success'] else 'failure'}", fontsize=10)
    fig.tight_layout()
    legend_below(fig, axes)
    return atomic_save(
        path, ".png", lambda tmp: fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    )


def write_switch_gif(
    path,
    task,
    ep: dict,
    *,
    fps: int = 12,
    max_frames: int = 40,
    title: str | None = None,
    dpi: int = 70,
) -> Path:
    """An animated GIF of one episode (``PillowWriter``); returns the path."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    idx = frame_indices(len(ep["envs"]), None, int(max_frames))
    fig = new_figure((5.6, 4.2))
    ax = fig.add_axes((0.12, 0.1, 0.55, 0.82))  # room on the right for the legend
    head = title or "moving can / target"

    def update(t):
        ax.clear()
        draw_episode_frame(ax, task, ep, t=t, legend=True)
        ax.set_title(f"{head}, t = {t * ep['dt']:.2f} s", fontsize=8)
        return ()

    anim = FuncAnimation(fig, update, frames=idx, blit=False, repeat=False)
    return atomic_save(
        path, ".gif", lambda tmp: anim.save(tmp, writer=PillowWriter(fps=int(fps)), dpi=dpi)
    )


# ----------------------------------------------------------------------------- the experiment's set
def experiment_figures(
    out_dir, task, model, off_model, test_envs, res, off_loop, episodes, metrics
) -> None:
    """Every figure of :func:`protorch.experiments.arm_reach.run` into ``out_dir``."""
    out_dir = Path(out_dir)
    promp = model.promp
    with torch.no_grad():
        # the test environments whose can is closest to the straight path: both classes matter there
        s = torch.tensor(task.start[:2], dtype=test_envs.dtype)
        g, c = test_envs[:, 2:].cpu(), test_envs[:, :2].cpu()
        u = (((c - s) * (g - s)).sum(-1) / (g - s).square().sum(-1)).clamp(0, 1)
        off_line = (c - s - u[:, None] * (g - s)).norm(dim=-1)
        pick = torch.argsort(off_line)[:6].tolist()
        env = test_envs[pick]
        known = torch.unique(model.env_map.labels).tolist()
        paths = {
            k: task.ee_path(promp.trajectory(model.env_map.predict_mean(env, k))) for k in known
        }

        best = label_aware_mean(
            model.env_map, promp, task, env, dtype=promp.basis.dtype, check=True
        )
        ok = task.success(promp.trajectory(best.mean), env)
        off = (
            None
            if off_model is None
            else task.ee_path(promp.trajectory(off_model.env_map.predict_mean(env)))
        )
    fig = new_figure((3.2 * 3, 3.4 * 2))
    axes = fig.subplots(2, 3, squeeze=False)
    for i, ax in enumerate(axes.flat):
        lines = {}
        for k in known:
            chosen = int(best.label[i]) == k
            lines[f"{_NAMES.get(k, k)}{' (chosen)' if chosen else ''}"] = (
                paths[k][i],
                CLASS_COLORS.get(k, "m"),
                "-" if chosen else ":",
            )
        if off is not None:
            lines["labels off (averaged)"] = (off[i], "0.35", "--")
        plot_top_view(
            ax,
            task,
            env[i],
            lines,
            title=f"held-out env {pick[i]}: {'success' if ok[i] else 'failure'}",
        )
    fig.suptitle(
        f"end-effector paths of both classes' predicted means (top view); test success "
        f"{metrics['test']['success_rate']:.3f}",
        fontsize=10,
    )
    fig.tight_layout()
    legend_below(fig, axes, ncol=5)
    atomic_save(
        out_dir / "top_view.png",
        ".png",
        lambda tmp: fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight"),
    )

    # 3-D view of the arm along the chosen mean of the first of those environments
    fig = new_figure((6, 5.5))
    ax = fig.add_subplot(projection="3d")
    with torch.no_grad():
        q = promp.trajectory(best.mean[0])  # (T, 7)
    plot_arm_3d(ax, task, q, env[0])
    ax.set_title(
        f"{task.robot.name} along the {_NAMES.get(int(best.label[0]), '')} mean, held-out env "
        f"{pick[0]}",
        fontsize=9,
    )
    atomic_save(out_dir / "arm_3d.png", ".png", lambda tmp: fig.savefig(tmp, dpi=110, format="png"))

    # held-out success vs loop iteration
    fig = new_figure((6, 4))
    ax = fig.subplots()
    for name, r, color in (
        ("labels on", res, "tab:green"),
        ("labels off (loop)", off_loop, "tab:red"),
    ):
        if r is None:
            continue
        ax.plot(
            [m["envs_done"] for m in r.metrics],
            [m["eval_success"] for m in r.metrics],
            "-o",
            ms=3,
            color=color,
            label=f"{name}: held-out test",
        )
        ax.plot(
            [m["envs_done"] for m in r.metrics[1:]],
            [m["initial_success"] / m["batch"] for m in r.metrics[1:]],
            ":",
            color=color,
            lw=1,
            label=f"{name}: GP guess on the next batch",
        )
    ax.set_xlabel("environments tried")
    ax.set_ylabel("success rate of the map's mean")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7)
    ax.set_title("arm: self-improvement, success vs loop iteration", fontsize=10)
    atomic_save(
        out_dir / "success_vs_iteration.png",
        ".png",
        lambda tmp: fig.savefig(tmp, dpi=110, format="png"),
    )

    # a moving episode in which the arm switches sides
    if episodes is not None:
        sw, okd = episodes.switches, episodes.success
        order = (
            [i for i in range(episodes.num_episodes) if sw[i] > 0 and okd[i]]
            + [i for i in range(episodes.num_episodes) if sw[i] > 0]
            + [0]
        )
        i = order[0]
        ep = episodes.episode(i)
        title = f"episode {i}, {int(sw[i])} switch(es)"
        plot_switch_frames(out_dir / "switch_frames.png", task, ep, title=title)
        write_switch_gif(out_dir / "switch_episode.gif", task, ep, title=title)
