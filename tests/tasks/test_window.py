"""The Fig. 4 window task: its three objectives against hand-computed values, and each objective
alone (what the loop's evaluation computes for PRO's per-objective steps) equal to its column of
the costs bit for bit, on the full trajectory and on the two time steps it reads."""

from __future__ import annotations

import math

import pytest
import torch

from protorch import ProMP
from protorch.loop.phases import Evaluator
from protorch.tasks import WindowTask


def test_costs_are_the_start_window_and_end_distances():
    task = WindowTask()  # start (0.1, 0.1), centre (0.5, 0.5), end (0.9, 0.9)
    traj = torch.tensor(
        [[0.1, 0.4], [0.5, 0.8], [0.9, 0.9], [0.9, 0.6]], dtype=torch.float64
    )  # (T=4, 2)
    c = task.costs(traj)  # (3,)
    # start 0.3 away along y; nearest sample to the centre (0.5, 0.8) is 0.3 away; end 0.3 away
    torch.testing.assert_close(
        c, torch.tensor([0.3, 0.3, 0.3], dtype=torch.float64), rtol=0, atol=1e-15
    )
    assert math.isclose(
        float(task.costs(traj[:1])[1]), math.hypot(0.4, 0.1), rel_tol=1e-15
    )  # one step


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_each_objective_alone_is_its_column_of_the_costs_bit_for_bit(dtype):
    task = WindowTask()
    demos = task.demonstrations(5, generator=torch.Generator().manual_seed(0), dtype=dtype)
    promp = ProMP(2, 10, 100, dtype=dtype).fit(demos)
    ev = Evaluator.build(task, promp, eval_dtype=None, sample_steps=None, labeler=None, dtype=dtype)
    g = torch.Generator().manual_seed(1)
    for batch in ((3, 7), (40, 100)):  # (B, S): a tail and whole vector blocks
        w = promp.mean + promp.var.sqrt() * torch.randn(
            *batch, promp.num_weights, generator=g, dtype=dtype
        )
        traj = promp.trajectory(w)  # (B, S, T, 2), the einsum's own memory layout
        full = task.costs(traj)  # (B, S, 3)
        for o in range(3):
            assert torch.equal(task.objective_cost(traj, o), full[..., o])
            steps = task.objective_steps(o)
            part = (
                traj if steps is None else ev.sample_trajectory(w, steps)
            )  # only the steps it reads
            assert torch.equal(task.objective_cost(part, o), full[..., o])
    assert task.objective_steps(1) is None and task.objective_steps(0) == task.objective_steps(
        2
    ) == (0, -1)


def test_bad_index_or_shape_is_refused():
    task = WindowTask()
    traj = torch.zeros(4, 10, 2)
    for bad in (3, -1):
        with pytest.raises(ValueError, match="index"):
            task.objective_cost(traj, bad)
        with pytest.raises(ValueError, match="index"):
            task.objective_steps(bad)
    with pytest.raises(ValueError, match=r"\(\.\.\., T, 2\)"):
        task.objective_cost(torch.zeros(4, 10, 3), 1)
    with pytest.raises(ValueError, match=r"\(\.\.\., T, 2\)"):
        task.costs(torch.zeros(10))
