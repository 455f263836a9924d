"""Where the arm's environments come from (protorch/tasks/arm/workspace.py): the prior grid over
the whole table (count, ranges, every node valid and its straight prior followed by the IK), the
reach bounds against the IK, the can clear of the start posture, the table sampler, bad settings."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.tasks import ArmReachTask
from protorch.tasks.arm.workspace import (
    can_clear_of_start,
    goal_in_reach,
    prior_grid_nodes,
    straight_prior_ok,
)

F64 = torch.float64


@pytest.fixture(scope="module")
def task():
    return ArmReachTask()


@pytest.fixture(scope="module")
def table_grid(task):
    return prior_grid_nodes(task, 2004, "table")


@pytest.mark.slow
def test_table_grid_has_the_count_the_ranges_and_only_valid_nodes(task, table_grid):
    grid, rep = table_grid
    assert grid.shape == (2004, 4) and grid.unique(dim=0).shape[0] == 2004
    assert rep["over"] == "table" and rep["kept"] == 2004 and rep["nodes"] == rep["per_axis"] ** 4
    # every node of the full grid is accounted for: removed by one rule, or valid
    removed = (
        rep["too_close"] + rep["goal_out_of_reach"] + rep["can_on_start_posture"] + rep["ik_failed"]
    )
    assert removed + rep["valid"] == rep["nodes"] and rep["valid"] >= 2004
    # a regular grid over the table: the can spans it all, the targets all of its width
    (x0, x1), (y0, y1) = task.table
    k = rep["per_axis"]
    assert all(len(grid[:, j].unique()) <= k for j in range(4))
    assert torch.allclose(grid[:, :2].amin(0), torch.tensor([x0, y0], dtype=F64))
    assert torch.allclose(grid[:, :2].amax(0), torch.tensor([x1, y1], dtype=F64))
    assert math.isclose(float(grid[:, 3].min()), y0) and math.isclose(float(grid[:, 3].max()), y1)
    # wider than the sampler's rectangles in every coordinate
    (cx, _), (gx, gy) = task.can_box, task.goal_box
    assert float(grid[:, 0].min()) < cx[0] and float(grid[:, 0].max()) > cx[1]
    assert float(grid[:, 2].min()) < gx[0] and float(grid[:, 3].max()) > gy[1]
    task.check_envs(grid)  # on the table
    assert bool(task.valid_envs(grid, "table").all())
    s = torch.tensor(task.start[:2], dtype=F64)
    for a, b in ((grid[:, :2], grid[:, 2:]), (grid[:, :2], s), (grid[:, 2:], s)):
        assert float((a - b).norm(dim=-1).min()) >= task.min_separation - 1e-12
    r = grid[:, 2:].norm(dim=-1)
    assert float(r.min()) >= task.reach[0] and float(r.max()) <= task.reach[1]


@pytest.mark.slow
def test_every_table_prior_is_followed_to_its_target(task, table_grid):
    grid, _ = table_grid
    goals = grid[:, 2:].unique(dim=0)  # (G, 2) the straight path does not depend on the can
    env = torch.cat([grid[:1, :2].expand(goals.shape[0], 2), goals], 1)
    q, err = task.ik_path(task.straight_paths(env, 100))
    end = task.ee_path(q[:, -1])
    assert float((end - task.goal_point(env)).norm(dim=-1).max()) <= task.goal_tol
    assert float(err.max()) <= task.goal_tol and bool(task.kinematics.within_limits(q).all())


@pytest.mark.slow
def test_reach_bounds_match_what_the_ik_reaches(task):
    # targets on the table just inside (r = 0.31, 0.79) and outside (r = 0.20 to 0.25, 0.86 to 0.87)
    # the reach annulus [0.30, 0.80]
    ring = [
        r * torch.stack([a.cos(), a.sin()], -1)
        for r, a in (
            (0.31, torch.linspace(-0.8, 0.8, 5, dtype=F64)),
            (0.79, torch.linspace(-0.6, 0.6, 5, dtype=F64)),
        )
    ]
    inside = torch.cat(ring)
    outside = torch.tensor(
        [[0.2, 0.0], [0.22, 0.1], [0.86, 0.0], [0.8, 0.35], [0.7, 0.5]], dtype=F64
    )
    wrap = lambda goals: torch.cat([torch.zeros_like(goals), goals], 1)
    assert bool(goal_in_reach(task, wrap(inside)).all()) and not bool(
        goal_in_reach(task, wrap(outside)).any()
    )
    assert bool(straight_prior_ok(task, inside).all())
    assert not bool(straight_prior_ok(task, outside).any())
    env = torch.cat([torch.tensor([[0.55, 0.4]], dtype=F64).expand(5, 2), outside], 1)
    assert not bool(task.valid_envs(env, "table").any())  # the table rules refuse them


def test_the_can_must_stand_clear_of_the_start_posture(task):
    # under the hand (2-3 cm from the start's end effector) versus well away from the arm
    env = torch.tensor(
        [[0.40, 0.02, 0.70, 0.30], [0.42, -0.03, 0.70, 0.30], [0.60, 0.30, 0.70, 0.0]], dtype=F64
    )
    assert can_clear_of_start(task, env).tolist() == [False, False, True]
    assert not bool(task.valid_envs(env[:2], "table").any())


def test_table_sampler_draws_valid_environments_wider_than_the_rectangles(task):
    e = task.sample_envs(400, torch.Generator().manual_seed(1), region="table")
    assert e.shape == (400, 4) and bool(task.valid_envs(e, "table").all())
    task.check_envs(e)
    assert (
        float(e[:, 0].min()) < 0.4
        and float(e[:, 1].abs().max()) > 0.4
        and float(e[:, 2].min()) < 0.4
    )
    again = task.sample_envs(400, torch.Generator().manual_seed(1), region="table")
    assert torch.equal(e, again)
    # the default region is the rectangles, and a task built for the table draws there by default
    rect = task.sample_envs(50, torch.Generator().manual_seed(2))
    assert torch.equal(
        rect, task.sample_envs(50, torch.Generator().manual_seed(2), region="rectangles")
    )
    wide = ArmReachTask(region="table")
    assert torch.equal(
        wide.sample_envs(50, torch.Generator().manual_seed(2)),
        task.sample_envs(50, torch.Generator().manual_seed(2), region="table"),
    )
    # every environment of the rectangles is valid under the table's rules too
    assert bool(
        task.valid_envs(task.sample_envs(2000, torch.Generator().manual_seed(3)), "table").all()
    )


def test_bad_regions_and_reach_are_refused(task):
    with pytest.raises(ValueError, match="^region must be one of rectangles, table, got 'floor'$"):
        ArmReachTask(region="floor")
    with pytest.raises(ValueError, match="reach must be"):
        ArmReachTask(reach=(0.8, 0.3))
    with pytest.raises(ValueError, match="reach must be"):
        ArmReachTask(reach=0.5)
    with pytest.raises(
        ValueError, match="^prior_grid must be one of rectangles, table, got 'room'$"
    ):
        prior_grid_nodes(task, 10, "room")
