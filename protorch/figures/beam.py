"""Figures of the beam-through-a-window experiment (the paper's Fig. 5): helpers take an ``ax``
(a 3-D one where they draw in space) and return it; :func:`fig5_figure` and
:func:`teleop_figure` assemble and save the experiment's two PNGs."""

from __future__ import annotations

import numpy as np
import torch

from .common import to_numpy
from .paper import save_figure

__all__ = [
    "plot_wall_3d",
    "plot_paths_3d",
    "plot_beam_3d",
    "plot_quaternion_components",
    "plot_stiffness",
    "plot_paths_top",
    "fig5_figure",
    "teleop_figure",
]

_QUAT_NAMES = ("q_w", "q_x", "q_y", "q_z")


def plot_wall_3d(
    ax,
    task,
    *,
    margin: float = 0.35,
    color: str = "0.6",
    alpha: float = 0.35,
    view: tuple[float, float] | None = (22.0, -130.0),
):
    """The wall around the window (a ``margin`` wide frame of it), start and end positions; the
    camera (``view = (elevation, azimuth)`` in degrees, ``None``: matplotlib's) looks at the
    window from the start's side at an angle, so both the opening and the path show."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    c = np.asarray(task.wall_position)
    rot = to_numpy(task.wall_rotation())
    u, v = rot[:, 1], rot[:, 2]  # width, height directions
    hw, hh = task.window_width / 2, task.window_height / 2
    ow, oh = hw + margin, hh + margin

    def quad(y0, y1, z0, z1):
        return [c + y * u + z * v for y, z in ((y0, z0), (y1, z0), (y1, z1), (y0, z1))]

    panels = [
        quad(-ow, -hw, -oh, oh),
        quad(hw, ow, -oh, oh),
        quad(-hw, hw, hh, oh),
        quad(-hw, hw, -oh, -hh),
    ]
    ax.add_collection3d(
        Poly3DCollection(panels, facecolor=color, edgecolor="0.3", alpha=alpha, lw=0.5)
    )
    window = np.array(quad(-hw, hw, -hh, hh) + [quad(-hw, hw, -hh, hh)[0]])
    ax.plot(window[:, 0], window[:, 1], window[:, 2], color="k", lw=1.2)
    ax.scatter(*task.start_position, color="g", marker="x", s=50, depthshade=False)
    ax.scatter(*task.end_position, color="r", marker="x", s=50, depthshade=False)
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.set_zlabel("z (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    # one scale on every axis (metres look like metres), around the wall, start and end
    pts = np.concatenate(
        [np.array(panels).reshape(-1, 3), [task.start_position, task.end_position]]
    )
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c0 in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c0 - half, c0 + half)
    ax.set_box_aspect((1, 1, 1))
    if view is not None:
        ax.view_init(elev=view[0], azim=view[1])
    return ax


def plot_paths_3d(
    ax, positions, *, color, lw: float = 1.0, alpha: float = 1.0, label: str | None = None
):
    """Position paths ``(n, T, 3)`` or ``(T, 3)`` (or a list of ``(T_i, 3+)``)."""
    paths = (
        [to_numpy(p) for p in positions]
        if isinstance(positions, (list, tuple))
        else to_numpy(positions)
    )
    if isinstance(paths, np.ndarray) and paths.ndim == 2:
        paths = [paths]
    colors = color if isinstance(color, (list, tuple)) else [color] * len(paths)
    for i, (p, col) in enumerate(zip(paths, colors)):
        ax.plot(
            p[:, 0],
            p[:, 1],
            p[:, 2],
            color=col,
            lw=lw,
            alpha=alpha,
            label=label if i == 0 else None,
        )
    return ax


def plot_beam_3d(ax, task, poses, *, cmap: str = "viridis", lw: float = 2.5):
    """The beam as a segment at each pose ``(P, 7)``, coloured from early to late."""
    import matplotlib

    a, b = task.beam_endpoints(poses)
    a, b = to_numpy(a), to_numpy(b)
    colors = matplotlib.colormaps[cmap](np.linspace(0, 1, len(a)))
    for pa, pb, col in zip(a, b, colors):
        ax.plot([pa[0], pb[0]], [pa[1], pb[1]], [pa[2], pb[2]], color=col, lw=lw)
    return ax


def plot_quaternion_components(
    ax,
    phase,
    quaternions,
    *,
    components=(0, 1, 2),
    via_phases=None,
    via=None,
    style: str = "-",
    label_prefix: str = "",
    lw: float = 1.8,
):
    """Quaternion components ``(T, 4)`` over the phase ``(T,)`` (the first three by default, as
    Fig. 5), with via quaternions ``(V, 4)`` at ``via_phases (V,)`` as markers, each drawn with the
    sign of the curve at its phase (``q`` and ``-q`` are the same orientation)."""
    z, q = to_numpy(phase), to_numpy(quaternions)
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
    if via is not None:
        vz, v = to_numpy(via_phases), to_numpy(via)  # (V,), (V, 4)
        at = q[np.abs(z[None, :] - vz[:, None]).argmin(1)]  # (V, 4) the curve at the via phases
        v = np.where(((v * at).sum(-1) < 0)[:, None], -v, v)
    for k in components:
        ax.plot(z, q[:, k], style, color=colors[k], lw=lw, label=f"{label_prefix}{_QUAT_NAMES[k]}")
        if via is not None:
            ax.plot(vz, v[:, k], "o", color=colors[k], ms=7, mfc="none", mew=2)
    ax.set_xlabel("phase")
    ax.set_ylabel("quaternion component")
    return ax


def plot_stiffness(ax, phase, stiffness, *, label: str, color: str):
    """A stiffness profile ``(T,)`` over the phase, log scale."""
    ax.semilogy(to_numpy(phase), np.maximum(to_numpy(stiffness), 1e-6), color=color, label=label)
    ax.set_xlabel("phase")
    return ax


def plot_paths_top(ax, task, positions, ok, *, title: str):
    """Top view (x-y) of paths ``(n, T, 3+)`` (green: success, red: failure) and the wall line."""
    rot = to_numpy(task.wall_rotation())
    c = np.asarray(task.wall_position)
    hw = task.window_width / 2
    for y0, y1 in ((-0.6, -hw), (hw, 0.6)):
        seg = np.array([c + y0 * rot[:, 1], c + y1 * rot[:, 1]])
        ax.plot(seg[:, 0], seg[:, 1], color="k", lw=4)
    paths, good = [to_numpy(x) for x in positions], to_numpy(ok).astype(bool)
    for path, g in zip(paths, good):
        ax.plot(path[:, 0], path[:, 1], color="tab:green" if g else "tab:red", lw=0.7, alpha=0.6)
    ax.plot(*task.start_position[:2], "gx", ms=9, mew=2)
    ax.plot(*task.end_position[:2], "rx", ms=9, mew=2)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    return ax


def fig5_figure(path, task, demos, demo_hits, demo_model, model, samples, phases) -> None:
    """Fig. 5: demonstrated positions, optimised samples, the first three quaternion components
    of the optimised mean with the via points, and the beam passing the window (3-D)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(15, 11))
    ax = fig.add_subplot(2, 2, 1, projection="3d")
    plot_wall_3d(ax, task)
    hits = [bool(h) for h in demo_hits]
    plot_paths_3d(
        ax, [d[:, :3] for d in demos], color=["tab:red" if h else "tab:green" for h in hits], lw=1
    )
    ax.set_title(
        f"(a) {len(demos)} demonstrated positions ({sum(hits)} hit the wall, red)", fontsize=10
    )
    ax = fig.add_subplot(2, 2, 2, projection="3d")
    plot_wall_3d(ax, task)
    plot_paths_3d(ax, samples[..., :3], color="tab:blue", lw=0.6, alpha=0.5, label="samples")
    mean = model.mean_trajectory()
    plot_paths_3d(ax, mean[:, :3], color="k", lw=2, label="mean")
    via = task.via_array()
    ax.scatter(*to_numpy(via[:, :3]).T, color="m", s=40, depthshade=False, label="via points")
    ax.legend(fontsize=7)
    ax.set_title(f"(b) optimised ProMP: mean and {len(samples)} samples", fontsize=10)
    ax = fig.add_subplot(2, 2, 3)
    plot_quaternion_components(ax, model.phase, mean[:, 3:], via_phases=phases, via=via[:, 3:])
    plot_quaternion_components(
        ax,
        demo_model.phase,
        demo_model.mean_trajectory()[:, 3:],
        style="--",
        label_prefix="demos' mean ",
        lw=1.0,
    )
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(
        "(c) first three quaternion components of the optimised mean (solid), via points (circles)",
        fontsize=10,
    )
    ax = fig.add_subplot(2, 2, 4, projection="3d")
    plot_wall_3d(ax, task, alpha=0.25)
    idx = torch.linspace(0, mean.shape[0] - 1, 16).round().long()
    plot_beam_3d(ax, task, mean[idx])
    plot_paths_3d(ax, mean[:, :3], color="k", lw=1)
    ax.set_title("(d) the beam along the optimised mean (early: dark, late: yellow)", fontsize=10)
    save_figure(fig, path)


def teleop_figure(path, task, guide, intended, assisted, free_ok, guided_ok, lengths) -> None:
    """Guidance stiffness over the phase, and top views of unassisted and assisted trials."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    z = torch.linspace(0, 1, guide.num_steps)
    ax = axes[0]
    plot_stiffness(ax, z, guide.stiffness[:, :3].mean(-1), label="position (N/m)", color="tab:blue")
    plot_stiffness(
        ax, z, guide.stiffness[:, 3:].mean(-1), label="quaternion (per unit)", color="tab:orange"
    )
    ax.set_ylabel("stiffness K(z) = clip(gain / std)")
    ax.legend(fontsize=8)
    ax.set_title("guidance stiffness (mean over coordinates)", fontsize=9)
    n = min(30, intended.shape[0])
    panels = (
        (axes[1], intended, free_ok, "unassisted"),
        (axes[2], assisted, guided_ok, "assisted"),
    )
    for ax, trials, ok, name in panels:
        paths = [t[: int(k)] for t, k in zip(trials[:n, :, :3], lengths[:n])]
        rate = float(ok.double().mean())
        title = f"{name}: success {rate:.2f} over {len(ok)} trials (first {n} shown)"
        plot_paths_top(ax, task, paths, ok[:n], title=title)
    save_figure(fig, path)
