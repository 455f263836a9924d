"""The two readings of the arm objectives' deviation ``d`` (protorch.tasks.arm.deviation)."""

import pytest
import torch

from protorch.tasks.arm.deviation import deviation, segment_deviation, time_aligned_deviation
from protorch.tasks.arm.reach import ArmReachTask

F64 = torch.float64
S = torch.tensor([0.0, 0.0, 0.1], dtype=F64)
G = torch.tensor([1.0, 0.0, 0.1], dtype=F64)


def test_a_path_on_the_line_at_the_wrong_pace_costs_only_in_time():
    u = torch.linspace(0, 1, 11, dtype=F64) ** 2  # along the segment, slow then fast
    p = S + u[:, None] * (G - S)  # (11, 3)
    assert float(segment_deviation(p, S, G).abs().max()) < 1e-12
    t = torch.linspace(0, 1, 11, dtype=F64)
    assert torch.allclose(
        time_aligned_deviation(p, S, G), (t - t**2).abs()
    )  # |u(t) - t| along the line
    # at constant speed both readings are 0; off the line by h both give h where the foot is on it
    lin = S + t[:, None] * (G - S)
    assert float(time_aligned_deviation(lin, S, G).max()) < 1e-12
    off = lin + torch.tensor([0.0, 0.05, 0.0], dtype=F64)
    assert torch.allclose(segment_deviation(off, S, G), torch.full((11,), 0.05, dtype=F64))
    assert torch.allclose(time_aligned_deviation(off, S, G), torch.full((11,), 0.05, dtype=F64))


def test_the_task_setting_switches_the_objectives_d():
    task_t = ArmReachTask(deviation="time")
    task_s = ArmReachTask()
    env = torch.tensor([0.56, 0.1, 0.70, 0.0], dtype=F64)
    g = task_s.goal_point(env)
    s = task_s.start_position(F64)
    u = torch.linspace(0, 1, 25, dtype=F64) ** 3
    path = s + u[:, None] * (g - s)  # on the segment, far from constant speed
    cs, ct = task_s.path_costs(path, env), task_t.path_costs(path, env)
    d_t = time_aligned_deviation(path, s, g).mean()
    assert torch.allclose(ct - cs, d_t.expand(3), atol=1e-12)  # d enters each objective once
    with pytest.raises(ValueError, match="deviation must be one of"):
        ArmReachTask(deviation="area")
    with pytest.raises(ValueError, match="deviation must be one of"):
        deviation("area", path, s, g)
