"""Figures a reader understands: labelled axes, legends that cover no data, one DoF's weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from protorch.figures.common import legend_below, new_figure
from protorch.figures.online import draw_online_frame, past_path_split
from protorch.figures.paper import plot_point_particle, plot_relevance, plot_window
from protorch.tasks import PointParticleTask, WindowTask


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_legend_below_covers_no_axes_and_lists_each_label_once():
    fig = new_figure((8, 3))
    axes = fig.subplots(1, 3)
    for ax in axes:
        ax.plot([0, 1], [0, 1], label="mean")
        ax.plot([0, 1], [1, 0], label="samples")
    fig.tight_layout()
    leg = legend_below(fig, axes)
    assert [t.get_text() for t in leg.get_texts()] == ["mean", "samples"]
    renderer = fig.canvas.get_renderer()
    box = leg.get_window_extent(renderer)
    assert not any(_overlaps(box, ax.get_window_extent(renderer)) for ax in axes)
    assert legend_below(new_figure((2, 2)), [new_figure((2, 2)).subplots()]) is None


def test_relevance_of_one_dofs_weights_and_its_labels():
    rel = torch.rand(3, 20, generator=torch.Generator().manual_seed(0))  # (O, N), 2 DoF x 10
    fig = new_figure((4, 3))
    ax = fig.subplots()
    plot_relevance(
        ax, rel[:, :10], ["start", "window", "end"], xlabel="x weight index", legend_loc="below"
    )
    lines = ax.get_lines()
    assert len(lines) == 3 and all(len(line.get_xdata()) == 10 for line in lines)
    np.testing.assert_allclose(lines[1].get_ydata(), rel[1, :10].numpy())
    assert ax.get_xlabel() == "x weight index" and "relevance" in ax.get_ylabel()
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert not _overlaps(
        ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    )


@pytest.mark.parametrize("panel", ["window", "particle", "online"])
def test_every_workspace_panel_has_axis_labels_with_units(panel):
    fig = new_figure((3, 3))
    ax = fig.subplots()
    if panel == "window":
        plot_window(ax, WindowTask())
    elif panel == "particle":
        task = PointParticleTask()
        plot_point_particle(ax, task, task.sample_envs(1, torch.Generator().manual_seed(0))[0])
    else:
        env = np.array([[1.0, 5.0, 5.0, 5.0, 9.0, 5.0]] * 3)  # (T+1, 6)
        pos = np.array([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]])
        draw_online_frame(ax, pos, env, np.repeat(pos[None], 3, 0), t=2, legend=True)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        assert not _overlaps(
            ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
        )
    assert (
        "(" in ax.get_xlabel() and "(" in ax.get_ylabel()
    )  # "x (unit square)", "y (workspace units)"


def test_every_marker_of_a_point_particle_panel_is_in_its_legend():
    task = PointParticleTask()
    fig = new_figure((3, 3))
    ax = fig.subplots()
    plot_point_particle(ax, task, task.sample_envs(1, torch.Generator().manual_seed(0))[0])
    drawn = [a for a in (*ax.get_lines(), *ax.patches)]
    assert drawn and all(
        not a.get_label().startswith("_") for a in drawn
    )  # nothing drawn without a label
    assert {"wall", "hole centre", "start", "goal"} <= {a.get_label() for a in drawn}


def test_the_path_before_the_wall_moved_is_faded():
    t = 30
    wall_x = np.r_[
        np.linspace(2.0, 5.0, 21), np.full(t + 1 - 21, 5.0)
    ]  # the wall moves, then stops at step 20
    env = np.column_stack(
        [
            np.full(t + 1, 1.0),
            np.full(t + 1, 5.0),
            wall_x,
            np.full(t + 1, 5.0),
            np.full(t + 1, 9.0),
            np.full(t + 1, 5.0),
        ]
    )  # (T+1, 6)
    assert (
        past_path_split(env, t, 5) == 20
    )  # solid since the wall stopped (more than the last 5 steps)
    assert past_path_split(env, 15, 5) == 10  # moving: the last 5 steps only
    assert past_path_split(env[:, [0, 1, 2, 3, 4, 5]] * 0 + 1, t, 5) == 0  # never moved: all solid
    pos = np.column_stack([np.linspace(1, 8, t + 1), np.full(t + 1, 5.0)])
    fig = new_figure((3, 3))
    ax = fig.subplots()
    draw_online_frame(ax, pos, env, np.repeat(pos[None], t + 1, 0), t=15, dt=0.01, recent=0.05)
    paths = {line.get_label(): line for line in ax.get_lines() if "path" in line.get_label()}
    faded = paths["path earlier, faded: the wall has moved since"]
    assert (
        faded.get_alpha() < 0.5
        and len(faded.get_xdata()) == 11
        and len(paths["path"].get_xdata()) == 6
    )
