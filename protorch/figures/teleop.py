"""The figure of ``experiment=teleop_window``: top views of the trials in each condition."""

from __future__ import annotations

import math
from pathlib import Path

from .common import atomic_save, new_figure, to_numpy

__all__ = ["teleop_figure"]


def teleop_figure(path, task, results: dict) -> Path:
    """``results``: ``{condition: run_trials(..., record=True)}``. One panel per condition: the
    beam's centre seen from above in every trial (green: success, red: touched the wall or did
    not arrive), each trial's wall at its first pose (grey) and where it ended (black)."""
    fig = new_figure((4.2 * len(results), 4.4))
    for i, (cond, r) in enumerate(results.items()):
        ax = fig.add_subplot(1, len(results), i + 1)
        poses, walls, ok = to_numpy(r["poses"]), to_numpy(r["walls"]), to_numpy(r["success"])
        for b in range(poses.shape[0]):
            ax.plot(
                poses[b, :, 0],
                poses[b, :, 1],
                color="tab:green" if ok[b] else "tab:red",
                lw=0.8,
                alpha=0.7,
            )
            for env, style in ((walls[b, 0], "0.6"), (walls[b, -1], "k")):
                c, yaw = env[:3], env[3]
                u = (-math.sin(yaw), math.cos(yaw))
                h = 0.5 * task.window_width
                for s in (-1, 1):  # the wall's two halves beside the window
                    ax.plot(
                        [c[0] + s * h * u[0], c[0] + s * 0.45 * u[0]],
                        [c[1] + s * h * u[1], c[1] + s * 0.45 * u[1]],
                        color=style,
                        lw=0.6,
                        alpha=0.5,
                    )
        ax.set_title(f"{cond}: success {ok.mean():.2f}")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal")
        ax.set_xlim(-0.1, 1.35)
        ax.set_ylim(-0.55, 0.55)
    fig.tight_layout()
    return atomic_save(path, ".png", lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
