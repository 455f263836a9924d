"""Geometric side switches (protorch.control.switches): a map without labels whose mean swings
from one side of the can to the other registers a switch the label count cannot see."""

from __future__ import annotations

import pytest
import torch

from protorch import ProMP
from protorch.control.arm import run_arm_episodes
from protorch.control.switches import count_changes, geometric_sides, geometric_switch_summary
from protorch.gp import make_env_map
from protorch.gp.model import EnvToProMP
from protorch.loop import demonstration_dataset
from protorch.tasks.arm.reach import LEFT, RIGHT, ArmReachTask

F64 = torch.float64
A = torch.tensor([0.56, 0.05, 0.72, 0.0], dtype=F64)  # can left of the start-target line
B = torch.tensor([0.56, -0.05, 0.72, 0.0], dtype=F64)  # can right of it


@pytest.fixture(scope="module")
def task():
    return ArmReachTask()


@pytest.fixture(scope="module")
def one_side_each(task):
    """Right-side demonstrations at A, left-side ones at B, one label: a single map whose mean
    passes right of the can at A and left of it at B (alpha large: no blending between them)."""
    g = torch.Generator().manual_seed(2)
    dr, er, _ = task.demonstrations(A[None], 2, g, sides=torch.tensor([RIGHT]), lengths=(30, 30))
    dl, el, _ = task.demonstrations(B[None], 2, g, sides=torch.tensor([LEFT]), lengths=(30, 30))
    promp = ProMP(7, 10, 50)
    ds = demonstration_dataset(promp, dr + dl, torch.cat([er, el]), var_floor=1e-3)
    model = EnvToProMP(promp, make_env_map("torch", 3000.0).fit(ds.env, ds.mean, ds.var))
    walk = A.repeat(1, 101, 1)  # 2 s at dt 0.02
    walk[:, 25:] = B  # the can moved across the line at a quarter of the motion
    return model, walk


def test_a_single_map_switches_geometrically_but_not_by_label(task, one_side_each):
    model, walk = one_side_each
    res = run_arm_episodes(model, task, walk=walk, duration=2.0, hold=0.5, dt=0.02)
    assert int(res.switches[0]) == 0  # one label: the label count sees nothing
    sides = geometric_sides(res, task)  # (1, T+1)
    assert sides.shape == res.labels.shape
    assert int(sides[0, 0]) == RIGHT and int(sides[0, -1]) == LEFT
    assert int(count_changes(sides)[0]) == 1
    # the same as classifying each recorded mean by hand
    traj = res.promp.trajectory(res.weights[0])  # (T+1, 50, 7)
    assert sides[0].tolist() == task.side(traj, res.envs[0]).tolist()
    s = geometric_switch_summary(res, task)
    assert s["switches_geometric"] == 1 and s["episodes_with_geometric_switch"] == 1


def test_record_false_is_refused(task, one_side_each):
    model, walk = one_side_each
    res = run_arm_episodes(model, task, walk=walk, duration=2.0, hold=0.5, dt=0.02, record=False)
    with pytest.raises(ValueError, match="record=True"):
        geometric_sides(res, task)
