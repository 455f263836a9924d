"""The arm-reaching task (Sec. IV-C): the exact segment-to-can distance, the objectives, success
(goal, can, joint limits), the homotopy label, the environment sampler and grid, the IK
demonstrator, and clear errors for environments off the table and wrong joint counts."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.primitives.promp import resample
from protorch.tasks import ArmReachTask
from protorch.tasks.arm.reach import LEFT, RIGHT, segment_axis_distance

F64 = torch.float64


@pytest.fixture(scope="module")
def task():
    return ArmReachTask()


@pytest.fixture(scope="module")
def straight(task):
    """Straight end-effector paths (IK, 60 steps) for three environments: the can far off the
    line, the can on the line, the can just beside it."""
    env = torch.tensor(
        [
            [0.62, -0.12, 0.70, 0.20],  # can 0.22 m off the start-target line
            [0.55, 0.00, 0.72, 0.00],  # can on the line
            [0.55, 0.04, 0.72, 0.00],
        ],
        dtype=F64,
    )  # 4 cm beside it: inside radius + margin
    q, err = task.ik_path(task.straight_paths(env, 60))
    assert float(err.max()) < 1e-4
    return env, q


def test_segment_axis_distance_is_exact(gen):
    a = torch.rand(400, 3, generator=gen, dtype=F64) * torch.tensor(
        [1, 1, 0.6], dtype=F64
    ) - torch.tensor([0.5, 0.5, 0.15], dtype=F64)
    b = torch.rand(400, 3, generator=gen, dtype=F64) * torch.tensor(
        [1, 1, 0.6], dtype=F64
    ) - torch.tensor([0.5, 0.5, 0.15], dtype=F64)
    b[:50] = a[:50]  # degenerate segments
    b[50:100, :2] = a[50:100, :2]  # vertical ones
    axis = torch.zeros(2, dtype=F64)
    exact = segment_axis_distance(a, b, axis, 0.0, 0.23)  # (400,)
    u = torch.linspace(0, 1, 4001, dtype=F64)[:, None, None]
    p = a + u * (b - a)  # (U, 400, 3)
    dz = torch.clamp(torch.maximum(p[..., 2] - 0.23, -p[..., 2]), min=0)
    brute = (p[..., :2].square().sum(-1) + dz.square()).sqrt().amin(0)  # (400,)
    assert bool((exact <= brute + 1e-12).all())  # never above a sampled distance ...
    assert torch.allclose(exact, brute, atol=1e-3)  # ... and equal up to the sampling


def test_costs_of_straight_paths(task, straight):
    env, q = straight
    c = task.costs(q, env)  # (3, 3)
    assert c.shape == (3, 3) and bool((c >= 0).all())
    # start and goal reached exactly, the path is the straight one (d ~ 0)
    assert float(c[:, 0].max()) < 2e-3 and float(c[:, 2].max()) < 2e-3
    assert float(c[0, 1]) < 2e-3  # the can 0.22 m away: no can cost
    # through the can: the full 0.2, less the spacing of the cost_steps samples around the can
    assert float(c[1, 1]) == pytest.approx(task.clearance, abs=0.02)
    assert float(ArmReachTask(cost_steps=None).costs(q[1], env[1])[1]) == pytest.approx(
        task.clearance, abs=5e-3
    )
    assert 0.14 < float(c[2, 1]) < 0.2  # 0.04 m beside the line
    ok = task.success(q, env)
    assert ok.tolist() == [True, False, False]
    assert float(task.can_distance(q[1], env[1])) < task.can_radius  # the hand goes through the can


def test_detour_passes_and_is_labelled_by_side(task, gen):
    env = torch.tensor([[0.56, 0.0, 0.72, 0.05]] * 2, dtype=F64)
    demos, denv, lab = task.demonstrations(
        env, 1, gen, sides=torch.tensor([LEFT, RIGHT]), lengths=(60, 60), goal_noise=0.0
    )
    q = torch.stack(demos)  # (2, 60, 7)
    assert lab.tolist() == [LEFT, RIGHT] and task.side(q, denv).tolist() == [LEFT, RIGHT]
    ee = task.ee_path(q)
    assert (
        float(ee[0, 30, 1]) > 0.1 and float(ee[1, 30, 1]) < -0.1
    )  # left is +y for a motion along +x
    assert task.success(q, denv).all()
    c = task.costs(
        q, denv
    )  # each objective is its own term plus d, the mean distance to the straight path
    # started exactly at s, so objective 0 is d alone
    assert (
        float((c[:, 1] - c[:, 0]).max()) < 0.1 and float(c[:, 0].min()) > 0.05
    )  # > 0.1 from the can, a detour


def test_success_needs_goal_limits_and_clearance(task, straight):
    env, q = straight
    q0, e0 = q[0], env[0]
    assert bool(task.success(q0, e0))
    off = e0.clone()
    off[3] += 0.03  # the target 3 cm further: the path ends 3 cm short
    assert not bool(task.success(q0, off))
    bad = q0.clone()
    bad[20:25, 3] = task.kinematics.lower[3] - 0.05  # joint 4 beyond its limit for a few steps
    assert not bool(task.success(bad, e0))
    # the success check uses every step, the objectives only cost_steps of them
    assert task.cost_indices(100).numel() == task.cost_steps and task.cost_indices(10).numel() == 10


def test_costs_broadcast_over_samples_and_envs(task, straight):
    env, q = straight
    samples = q[:, None].expand(3, 4, -1, -1)  # (B, S, T, 7)
    c = task.costs(samples, env[:, None])  # (B, S, 3)
    assert c.shape == (3, 4, 3) and torch.allclose(c[:, 2], task.costs(q, env))
    assert task.costs(q.float(), env.float()).dtype == torch.float32


def test_sampler_rectangles_separation_and_grid(task, gen):
    e = task.sample_envs(500, gen)
    (cx, cy), (gx, gy) = task.can_box, task.goal_box
    assert e.shape == (500, 4) and bool(task.valid_envs(e).all())
    for k, (lo, hi) in enumerate((cx, cy, gx, gy)):
        assert bool(((e[:, k] >= lo) & (e[:, k] <= hi)).all())
    assert task.sample_envs(7, torch.Generator().manual_seed(3)).equal(
        task.sample_envs(7, torch.Generator().manual_seed(3))
    )
    grid = task.prior_grid(2004)
    assert (
        grid.shape == (2004, 4)
        and grid.unique(dim=0).shape[0] == 2004
        and bool(task.valid_envs(grid).all())
    )
    k = round(len(grid[:, 0].unique()))  # a regular grid: few distinct values per axis
    assert all(len(grid[:, j].unique()) == k for j in range(4)) and k**4 >= 2004


@pytest.mark.slow
def test_ik_demonstrator(task, gen):
    env = task.sample_envs(3, gen)
    demos, denv, lab = task.demonstrations(env, 2, gen, lengths=(40, 50))
    assert len(demos) == 6 and denv.shape == (6, 4) and torch.equal(denv[::2], env)
    assert lab.tolist() == [
        LEFT,
        LEFT,
        RIGHT,
        RIGHT,
        LEFT,
        LEFT,
    ]  # alternating by environment, measured
    start = task.start_config()
    for d, e in zip(demos, denv):
        assert 40 <= d.shape[0] <= 50 and d.shape[1] == 7
        assert torch.allclose(d[0], start, atol=1e-4)  # hand-guided from where the robot stands
        assert bool(task.kinematics.within_limits(d).all())
        ee = task.ee_path(d)
        assert float((ee[-1] - task.goal_point(e)).norm()) < 0.05  # imperfect, but near the target
        assert float(task.can_distance(d, e)) > task.can_radius + task.margin  # clear of the can
        assert (
            float((ee[:, 2] - task.ee_height).abs().max()) < 0.06
        )  # over the table, at reach height
    traj = torch.stack([resample(d, 100) for d in demos])
    assert float(task.success(traj, denv).double().mean()) >= 0.5


# ----------------------------------------------------------------------------- bad input
def test_environments_off_the_table_are_refused(task, straight):
    _, q = straight
    with pytest.raises(ValueError, match=r"env\[1\] has can_x = 1\.2.*off the table"):
        task.costs(q[:2], torch.tensor([[0.55, 0.0, 0.7, 0.0], [1.2, 0.0, 0.7, 0.0]], dtype=F64))
    with pytest.raises(ValueError, match="goal_y = -0.8"):
        task.success(q[0], torch.tensor([0.55, 0.0, 0.7, -0.8], dtype=F64))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        task.costs(q[0], torch.zeros(6, dtype=F64))
    with pytest.raises(ValueError, match="NaN"):
        task.costs(q[0], torch.tensor([math.nan, 0, 0.7, 0], dtype=F64))
    bad = q[0].clone()
    bad[5, 2] = math.nan
    for fn in (task.costs, task.success):
        with pytest.raises(ValueError, match="NaN"):
            fn(bad, torch.tensor([0.55, 0.0, 0.7, 0.0], dtype=F64))
    with pytest.raises(ValueError, match="off the table"):
        task.demonstrations(torch.tensor([[0.55, 0.0, 0.95, 0.0]], dtype=F64), 2)
    with pytest.raises(ValueError, match="must lie on the table"):
        ArmReachTask(goal_box=((0.6, 1.2), (-0.2, 0.2)))


def test_wrong_joint_counts_are_refused(task):
    env = torch.tensor([0.55, 0.0, 0.7, 0.0], dtype=F64)
    for fn in (task.costs, task.success, task.side, task.can_distance):
        with pytest.raises(ValueError, match=r"\(\.\.\., T, 7\) joint trajectories"):
            fn(torch.zeros(10, 6, dtype=F64), env)
    with pytest.raises(ValueError, match="start_q must have 7"):
        ArmReachTask(start_q=(0.0,) * 6)
    with pytest.raises(ValueError, match="do not broadcast"):
        task.costs(torch.zeros(3, 10, 7, dtype=F64), env.expand(2, 4))
