"""The arm's demonstrator paths (protorch.tasks.arm.demos): the noiseless detour passes beside the
can at the distance and on the side asked for, from the start to the target."""

from __future__ import annotations

import pytest
import torch

from protorch.tasks import ArmReachTask
from protorch.tasks.arm.demos import beside_can, detour_paths
from protorch.tasks.arm.reach import LEFT, RIGHT

F64 = torch.float64


@pytest.fixture(scope="module")
def task():
    return ArmReachTask()


def test_a_detour_passes_the_can_on_its_side_at_its_distance(task):
    env = torch.tensor([[0.55, 0.00, 0.72, 0.00], [0.60, 0.10, 0.70, -0.15]], dtype=F64)
    for side in (LEFT, RIGHT):
        path = detour_paths(task, env, side, 0.2, 101)  # (2, 101, 3)
        assert path.shape == (2, 101, 3)
        assert torch.allclose(path[:, 0], task.start_position().expand(2, 3), atol=1e-12)
        assert torch.allclose(path[:, -1], task.goal_point(env), atol=1e-12)
        assert torch.allclose(
            path[..., 2], torch.full_like(path[..., 2], task.ee_height), atol=1e-12
        )
        # the via point beside the can is on the path (to the 101 samples' spacing), 0.2 m from the
        # can's axis;
        # the curve cuts in towards the can after it (the priors keep only the detours that
        # succeed), never into it
        via = beside_can(
            task, env, torch.full((2,), side), torch.full((2, 1), 0.2, dtype=F64)
        )  # (2, 2)
        assert torch.allclose((via - env[:, :2]).norm(dim=-1), torch.full((2,), 0.2, dtype=F64))
        assert float((path[..., :2] - via[:, None]).norm(dim=-1).amin(-1).max()) < 5e-3
        assert (
            float((path[..., :2] - env[:, None, :2]).norm(dim=-1).amin(-1).min())
            > 2 * task.can_radius
        )
        assert task.side_of_path(path, env).tolist() == [side, side]
    left = beside_can(task, env, torch.full((2,), LEFT), torch.full((2, 1), 0.2, dtype=F64))
    line = task.goal_point(env)[:, :2] - task.start_position()[:2]
    off = left - env[:, :2]
    assert (
        (line[:, 0] * off[:, 1] - line[:, 1] * off[:, 0]) > 0
    ).all()  # left: counter-clockwise of the line
    assert float((line * off).sum(-1).abs().max()) < 1e-12  # perpendicular to it


def test_a_detour_distance_must_be_positive(task):
    env = torch.tensor([[0.55, 0.00, 0.72, 0.00]], dtype=F64)
    with pytest.raises(ValueError, match="a detour's distance must be > 0, got 0"):
        detour_paths(task, env, LEFT, 0.0)
