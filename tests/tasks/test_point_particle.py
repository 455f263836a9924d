"""The point-particle task (Sec. IV-B): geometry, objectives and success against hand-computed
values, the environment sampler, batching, input checks and the synthetic demonstrator."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.tasks.point_particle import PointParticleTask, signed_distance_to_wall

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

# start (1, 5), wall x in [4, 6], hole y in (4, 6) centred at (5, 5), goal (9, 5)
ENV = torch.tensor([1.0, 5.0, 5.0, 5.0, 9.0, 5.0], dtype=F64)


def line(*points, steps: int = 0) -> torch.Tensor:
    """A polyline through ``points``; with ``steps`` > 0 each segment is sampled ``steps`` times."""
    p = torch.tensor(points, dtype=F64)  # (P, 2)
    if steps == 0:
        return p
    s = torch.linspace(0, 1, steps + 1, dtype=F64)[:-1, None]  # (steps, 1)
    segs = [p[i] + s * (p[i + 1] - p[i]) for i in range(len(p) - 1)]
    return torch.cat([*segs, p[-1:]])


# ------------------------------------------------------------------ signed distance
@pytest.mark.parametrize(
    "point, expected",
    [
        ((5.0, 5.0), 1.0),  # hole centre: 1 from both faces of the hole
        ((5.0, 5.5), 0.5),  # in the hole, 0.5 below the upper rectangle
        ((5.0, 8.0), -1.0),  # inside the upper rectangle, 1 from its sides
        ((4.5, 2.0), -0.5),  # inside the lower rectangle, 0.5 from its left face
        ((5.0, 4.2), 0.2),  # in the hole, just above the lower rectangle
        ((2.0, 5.0), math.sqrt(5.0)),  # left of the hole: to the corners (4, 4) and (4, 6)
        ((3.0, 9.0), 1.0),  # beside the upper rectangle
        ((7.0, 4.5), math.sqrt(1.25)),  # right of the hole, nearest the corner (6, 4)
        ((6.0, 8.0), 0.0),  # on the right face
    ],
)
def test_signed_distance_on_known_points(point, expected):
    task = PointParticleTask()
    sd = task.signed_distance_to_wall(torch.tensor(point, dtype=F64), ENV)
    assert sd.shape == ()
    assert float(sd) == pytest.approx(expected, abs=1e-12)


def test_signed_distance_beyond_the_workspace_depends_on_the_wall_option():
    pts = torch.tensor([[5.0, -0.5], [5.0, 0.2], [5.0, 10.5]], dtype=F64)
    infinite = PointParticleTask().signed_distance_to_wall(pts, ENV)
    bounded = PointParticleTask(infinite_wall=False).signed_distance_to_wall(pts, ENV)
    torch.testing.assert_close(infinite, torch.tensor([-1.0, -1.0, -1.0], dtype=F64))
    # the authors' rectangles end at y = 0 and y = 10
    torch.testing.assert_close(bounded, torch.tensor([0.5, -0.2, 0.5], dtype=F64))


def test_signed_distance_is_one_lipschitz_and_negative_exactly_inside(gen):
    task = PointParticleTask()
    env = task.sample_envs(50, gen)[:, None]  # (50, 1, 6)
    p = 10 * torch.rand(50, 400, 2, generator=gen, dtype=F64)  # (50, 400, 2)
    q = p + 0.05 * torch.randn(50, 400, 2, generator=gen, dtype=F64)
    sd_p, sd_q = task.signed_distance_to_wall(p, env), task.signed_distance_to_wall(q, env)
    assert bool(((sd_p - sd_q).abs() <= (p - q).norm(dim=-1) + 1e-12).all())
    wx, hy = env[..., 2], env[..., 3]  # (50, 1)
    inside = ((p[..., 0] - wx).abs() < 1) & ((p[..., 1] - hy).abs() > 1)  # (50, 400)
    assert bool(((sd_p < 0) == inside).all())


# ------------------------------------------------------------------ objectives
def test_costs_hole_objectives_by_hand():
    task = PointParticleTask()
    traj = line((2.0, 5.0), (5.0, 7.0), (8.0, 6.0))
    c = task.costs(traj, ENV)
    # start 1 off; nearest sample to the hole centre (5, 5) is (5, 7); goal (9, 5) vs (8, 6)
    torch.testing.assert_close(c, torch.tensor([1.0, 2.0, math.sqrt(2.0)], dtype=F64))
    straight = line((1.0, 5.0), (9.0, 5.0), steps=8)  # samples at x = 1, 2, ..., 9
    torch.testing.assert_close(task.costs(straight, ENV), torch.zeros(3, dtype=F64))
    assert task.objective_names == ("start", "hole", "goal") and task.num_objectives == 3


def test_costs_clearance_objective_by_hand():
    task = PointParticleTask(objectives="clearance")
    assert task.objective_names == ("start", "clearance", "goal")
    # the sample (5, 7) is 1 deep inside the upper rectangle: cost 1 - (-1) = 2
    c = task.costs(line((2.0, 5.0), (5.0, 7.0), (8.0, 6.0)), ENV)
    torch.testing.assert_close(c, torch.tensor([1.0, 2.0, math.sqrt(2.0)], dtype=F64))
    # through the hole centre: clearance 1, the best possible, cost 0
    straight = line((1.0, 5.0), (9.0, 5.0), steps=8)
    torch.testing.assert_close(task.costs(straight, ENV), torch.zeros(3, dtype=F64))
    # 0.5 above the centre: clearance 0.5, cost 0.5
    high = line((1.0, 5.5), (9.0, 5.5), steps=8)
    assert float(task.costs(high, ENV)[1]) == pytest.approx(0.5)
    assert float(task.clearance(high, ENV)) == pytest.approx(0.5)


def test_costs_are_nonnegative_on_random_paths(gen):
    for objectives in ("hole", "clearance"):
        task = PointParticleTask(objectives=objectives)
        env = task.sample_envs(20, gen)  # (20, 6)
        traj = 10 * torch.rand(20, 30, 8, 2, generator=gen, dtype=F64)  # (20, 30, T=8, 2)
        assert bool((task.costs(traj, env[:, None]) >= 0).all())


# ------------------------------------------------------------------ success and collisions
@pytest.mark.parametrize("objectives", ["hole", "clearance"])
def test_objective_cost_is_one_column_of_the_costs(objectives, gen):
    task = PointParticleTask(objectives=objectives)
    env = task.sample_envs(6, gen)[:, None]  # (6, 1, 6)
    traj = 10 * torch.rand(6, 5, 30, 2, generator=gen, dtype=F64)  # (6, 5, 30, 2)
    full = task.costs(traj, env)  # (6, 5, 3)
    for o in range(3):
        torch.testing.assert_close(
            task.objective_cost(traj, env, o), full[..., o], rtol=0, atol=1e-12
        )
    with pytest.raises(ValueError, match="index"):
        task.objective_cost(traj, env, 3)


@pytest.mark.parametrize("objectives", ["hole", "clearance"])
def test_an_objective_reads_only_its_time_steps_and_any_memory_layout_gives_the_same_numbers(
    objectives, gen
):
    task = PointParticleTask(objectives=objectives)
    env = task.sample_envs(6, gen)[:, None]  # (6, 1, 6)
    traj = 10 * torch.rand(6, 5, 30, 2, generator=gen, dtype=torch.float32)  # (6, 5, 30, 2)
    planes = (
        traj.permute(2, 3, 0, 1).contiguous().permute(2, 3, 0, 1)
    )  # the same values, x- and y-planes in memory
    full = task.costs(traj, env)  # (6, 5, 3)
    assert torch.equal(task.costs(planes, env), full)  # bit for bit, not only close
    for o in range(3):
        steps = task.objective_steps(o)
        part = traj if steps is None else traj[..., list(steps), :]  # only the steps it reads
        assert torch.equal(task.objective_cost(part, env, o), full[..., o])
    assert task.objective_steps(1) is None and task.objective_steps(0) == task.objective_steps(
        2
    ) == (0, -1)
    with pytest.raises(ValueError, match="index"):
        task.objective_steps(3)


def test_costs_are_differentiable_in_the_path(gen):
    """The in-place arithmetic of the signed distance leaves autograd's graph intact."""
    task = PointParticleTask(objectives="clearance")
    env = ENV.expand(4, 6)
    traj = (
        line((1, 5), (5, 4.6), (9, 5), steps=10).expand(4, -1, -1).clone().requires_grad_()
    )  # (4, 21, 2)
    task.costs(traj, env)[..., 1].sum().backward()
    ref = traj.detach().clone().requires_grad_()
    qx = (ref[..., 0] - 5.0).abs() - 1  # the formula written out of place: wall x 5, hole y 5
    qy = 1 - (ref[..., 1] - 5.0).abs()
    sd = torch.hypot(qx.clamp_min(0), qy.clamp_min(0)) + torch.maximum(qx, qy).clamp_max(
        0
    )  # (4, 21)
    (1 - sd.amin(-1)).clamp_min(0).sum().backward()
    torch.testing.assert_close(traj.grad, ref.grad, rtol=0, atol=0)
    assert bool(traj.grad.abs().sum() > 0)


def test_infinite_wall_signed_distance_matches_the_two_box_formula(gen):
    """The fast path (one box, the nearer rectangle) equals the minimum over both rectangles."""
    task = PointParticleTask()
    env = task.sample_envs(40, gen)[:, None]  # (40, 1, 6)
    p = -2 + 14 * torch.rand(
        40, 300, 2, generator=gen, dtype=F64
    )  # (40, 300, 2) also outside [0, 10]^2
    wx, hy = env[..., 2], env[..., 3]
    qx = ((p[..., 0] - wx).abs() - 1)[..., None]  # (40, 300, 1)
    qy = torch.stack([p[..., 1] - (hy - 1), (hy + 1) - p[..., 1]], -1)  # (40, 300, 2)
    qx = qx.expand_as(qy)
    ref = (torch.hypot(qx.clamp_min(0), qy.clamp_min(0)) + torch.maximum(qx, qy).clamp_max(0)).amin(
        -1
    )
    torch.testing.assert_close(task.signed_distance_to_wall(p, env), ref, rtol=0, atol=1e-12)


def test_success_through_the_hole_and_not_through_the_wall():
    task = PointParticleTask()
    # two samples only, both outside the wall: a check at the samples alone would miss the wall
    assert bool(task.success(line((1.0, 5.0), (9.0, 5.0)), ENV))
    env_high = torch.tensor([1.0, 8.0, 5.0, 5.0, 9.0, 8.0], dtype=F64)
    assert not bool(task.success(line((1.0, 8.0), (9.0, 8.0)), env_high))
    assert bool(task.collides(line((1.0, 8.0), (9.0, 8.0)), env_high))
    # down to the hole, through it, and back up: succeeds
    around = line((1.0, 8.0), (3.5, 5.0), (6.5, 5.0), (9.0, 8.0), steps=20)
    assert bool(task.success(around, env_high))
    # cutting the corner of the upper rectangle between two samples
    cut = line((1.0, 8.0), (4.5, 6.2), (9.0, 8.0))
    assert bool(task.collides(cut, env_high))


def test_success_endpoint_tolerance():
    task = PointParticleTask()
    ok = line((1.0, 5.19), (9.0, 5.0))
    assert bool(task.success(ok, ENV))
    assert not bool(task.success(line((1.0, 5.21), (9.0, 5.0)), ENV))
    assert not bool(task.success(line((1.0, 5.0), (9.0, 4.79)), ENV))
    assert bool(task.success(line((1.0, 5.0), (9.0, 4.79)), ENV, tol=0.25))


def test_touching_a_face_is_not_a_collision_but_entering_is():
    task = PointParticleTask()
    assert not bool(
        task.collides(line((1.0, 6.0), (9.0, 6.0)), ENV)
    )  # along the upper rectangle's face
    assert not bool(task.collides(line((1.0, 4.0), (9.0, 4.0)), ENV))  # along the lower one's
    assert bool(task.collides(line((1.0, 6.001), (9.0, 6.001)), ENV))
    assert bool(task.collides(line((5.0, 8.0), (5.0, 8.0)), ENV))  # a zero-length segment inside
    assert bool(task.collides(torch.tensor([[5.0, 8.0]], dtype=F64), ENV))  # a single sample inside
    assert not bool(task.collides(line((5.0, 5.0), (5.0, 5.5)), ENV))  # vertical, in the hole


def test_going_around_the_wall_outside_the_workspace():
    detour = line((1.0, 5.0), (1.0, 10.5), (9.0, 10.5), (9.0, 5.0))
    assert bool(PointParticleTask().collides(detour, ENV))  # the wall continues
    assert not bool(
        PointParticleTask(infinite_wall=False).collides(detour, ENV)
    )  # the authors' rectangles


def test_exact_collision_agrees_with_dense_resampling(gen):
    """Every collision found on a 100x resampled path is found by the exact test, and the two
    agree on almost every random path (they differ only for paths grazing the wall)."""
    task = PointParticleTask()
    env = task.sample_envs(400, gen)  # (400, 6)
    via = 10 * torch.rand(400, 4, 2, generator=gen, dtype=F64)  # (400, 4, 2)
    exact = task.collides(via, env)  # (400,)
    s = torch.linspace(0, 1, 101, dtype=F64)[:, None]  # (101, 1)
    dense = torch.cat(
        [via[:, i, None] + s * (via[:, i + 1, None] - via[:, i, None]) for i in range(3)], 1
    )  # (400, 303, 2)
    sd = task.signed_distance_to_wall(dense, env[:, None])  # (400, 303)
    dense_hit = (sd < 0).any(-1)  # (400,)
    assert bool((exact | ~dense_hit).all())  # dense hit => exact hit
    assert float((exact == dense_hit).double().mean()) >= 0.98
    assert 0.2 < float(exact.double().mean()) < 0.95  # the random paths are a real mix


# ------------------------------------------------------------------ environments
def test_sampler_ranges_and_constraints(gen):
    task = PointParticleTask()
    env = task.sample_envs(20000, gen)
    assert env.shape == (20000, 6) and env.dtype == F64 and task.env_dim == 6
    sx, sy, wx, hy, gx, gy = env.unbind(-1)
    assert float(wx.min()) >= 2 and float(wx.max()) <= 8
    assert float(wx.min()) < 2.01 and float(wx.max()) > 7.99  # the whole range is covered
    assert float(hy.min()) >= 1 and float(hy.max()) <= 9
    assert bool((sx >= 0).all()) and bool((sx <= wx - 1.5).all())
    assert bool((gx >= wx + 1.5).all()) and bool((gx <= 10).all())
    for y in (sy, gy):
        assert float(y.min()) >= 0 and float(y.max()) <= 10
        assert float(y.mean()) == pytest.approx(5.0, abs=0.1)
    assert float(wx.mean()) == pytest.approx(5.0, abs=0.05)
    # start_x | wall_x is uniform on [0, wall_x - 1.5]: its mean is half the range
    assert float((sx / (wx - 1.5)).mean()) == pytest.approx(0.5, abs=0.01)
    assert float(((gx - wx - 1.5) / (8.5 - wx)).mean()) == pytest.approx(0.5, abs=0.01)
    # reproducible from the generator
    a = task.sample_envs(5, torch.Generator().manual_seed(7))
    b = task.sample_envs(5, torch.Generator().manual_seed(7))
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert task.sample_envs(3, gen, dtype=torch.float32).dtype == torch.float32


def test_fixed_start_gives_the_papers_4d_environment(gen):
    task = PointParticleTask(fixed_start=(1.0, 5.0))
    assert task.env_dim == 4
    env = task.sample_envs(5000, gen)  # (5000, 4)
    assert env.shape == (5000, 4)
    full = task.full_env(env)  # (5000, 6)
    torch.testing.assert_close(full[:, 2:], env)
    assert bool((full[:, :2] == torch.tensor([1.0, 5.0], dtype=F64)).all())
    assert bool((full[:, 2] >= 2.5).all()) and bool((full[:, 2] <= 8).all())  # start keeps 1.5
    # a 4-D and the matching 6-D environment give the same costs; 6-D is accepted too
    traj = line((1.0, 5.0), (5.0, 5.0), (9.0, 5.0))
    e4 = torch.tensor([5.0, 5.0, 9.0, 5.0], dtype=F64)
    torch.testing.assert_close(task.costs(traj, e4), task.costs(traj, ENV))
    torch.testing.assert_close(task.full_env(e4[None].expand(3, 2, 4)), ENV.expand(3, 2, 6))
    with pytest.raises(ValueError, match="needs fixed_start"):
        PointParticleTask().costs(traj, e4)
    with pytest.raises(ValueError, match="fixed_start"):
        PointParticleTask(fixed_start=(7.0, 5.0))


# ------------------------------------------------------------------ batching, dtypes, devices
def test_batch_broadcasting_matches_a_loop(gen):
    for objectives in ("hole", "clearance"):
        task = PointParticleTask(objectives=objectives)
        env = task.sample_envs(4, gen)  # (B=4, 6)
        traj = 10 * torch.rand(4, 7, 12, 2, generator=gen, dtype=F64)  # (B, S=7, T, 2)
        c = task.costs(traj, env[:, None])  # (4, 7, 3)
        ok = task.success(traj, env[:, None])  # (4, 7)
        assert c.shape == (4, 7, 3) and ok.shape == (4, 7)
        for b in range(4):
            for s in range(7):
                torch.testing.assert_close(c[b, s], task.costs(traj[b, s], env[b]))
                assert bool(ok[b, s]) == bool(task.success(traj[b, s], env[b]))
        # one trajectory against many environments, and the other way round
        assert task.costs(traj[0, 0], env).shape == (4, 3)
        assert task.collides(traj[0], env[0]).shape == (7,)
        assert task.clearance(traj, env[:, None]).shape == (4, 7)
        assert task.signed_distance_to_wall(traj, env[:, None, None]).shape == (4, 7, 12)
        assert task.wall_rectangles(env).shape == (4, 2, 4)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtypes_and_devices(device, dtype, gen):
    task = PointParticleTask(objectives="clearance")
    env = task.sample_envs(8, gen)
    traj = 10 * torch.rand(8, 5, 20, 2, generator=gen, dtype=F64)
    ref_c, ref_ok = task.costs(traj, env[:, None]), task.success(traj, env[:, None])
    e, t = env.to(device, dtype), traj.to(device, dtype)
    c, ok = task.costs(t, e[:, None]), task.success(t, e[:, None])
    assert c.dtype == dtype and c.device.type == device and ok.device.type == device
    torch.testing.assert_close(c.cpu().double(), ref_c, rtol=1e-4, atol=1e-4)
    assert float((ok.cpu() == ref_ok).double().mean()) >= 0.95  # float32 may flip grazing paths
    demos, demo_envs = task.demonstrations(e[:2], 2, gen)
    assert (
        demos[0].dtype == dtype
        and demos[0].device.type == device
        and demo_envs.device.type == device
    )


def test_bad_input_raises_clear_errors():
    task = PointParticleTask()
    traj = line((1.0, 5.0), (9.0, 5.0))
    with pytest.raises(ValueError, match=r"traj must be \(\.\.\., T, 2\)"):
        task.costs(torch.zeros(5, 3, dtype=F64), ENV)
    with pytest.raises(ValueError, match="last dimension"):
        task.costs(traj, ENV[:5])
    with pytest.raises(ValueError, match="NaN"):
        task.costs(torch.tensor([[1.0, float("nan")], [2.0, 2.0]]), ENV)
    with pytest.raises(ValueError, match="NaN"):
        task.success(traj, torch.full((6,), float("nan")))
    with pytest.raises(ValueError, match="inf"):
        task.costs(traj.clone().fill_(float("inf")), ENV)
    with pytest.raises(ValueError, match="do not broadcast"):
        task.costs(traj.expand(3, 2, 2), ENV.expand(4, 6))
    with pytest.raises(ValueError, match="at least 2 dimensions"):
        task.costs(torch.zeros(2, dtype=F64), ENV)
    with pytest.raises(ValueError, match="points must be"):
        task.signed_distance_to_wall(torch.zeros(4, 3, dtype=F64), ENV)
    with pytest.raises(ValueError, match="objectives"):
        PointParticleTask(objectives="window")
    with pytest.raises(ValueError, match="tol"):
        task.success(traj, ENV, tol=-1.0)
    with pytest.raises(ValueError, match="per_env"):
        task.demonstrations(ENV[None], 0)


def test_module_function_matches_the_method(gen):
    task = PointParticleTask()
    env = task.sample_envs(3, gen)
    p = 10 * torch.rand(3, 50, 2, generator=gen, dtype=F64)
    torch.testing.assert_close(
        signed_distance_to_wall(p, env[:, None]), task.signed_distance_to_wall(p, env[:, None])
    )


# ------------------------------------------------------------------ synthetic demonstrator
def test_synthetic_demonstrator_is_imperfect_like_a_mouse():
    task = PointParticleTask()
    gen = torch.Generator().manual_seed(0)
    demos, envs = task.demonstrations(200, 3, gen)
    assert len(demos) == 600 and envs.shape == (600, 6)
    torch.testing.assert_close(envs[0::3], envs[1::3], rtol=0, atol=0)  # 3i..3i+2 share env i
    lengths = torch.tensor([len(d) for d in demos])
    assert int(lengths.min()) >= 200 and int(lengths.max()) <= 340
    assert int(lengths.max() - lengths.min()) > 100  # lengths really vary
    collide = torch.stack([task.collides(d, e) for d, e in zip(demos, envs)])
    frac = float(collide.double().mean())
    assert 0.15 <= frac <= 0.35, f"collision fraction {frac:.3f}"
    c = torch.stack([task.costs(d, e) for d, e in zip(demos, envs)])  # (600, 3)
    # start and end slightly off: never exact, mostly within the success tolerance
    assert float(c[:, 0].min()) > 0 and float(c[:, 2].min()) > 0
    assert (
        float((c[:, 0] <= 0.2).double().mean()) >= 0.9
        and float((c[:, 2] <= 0.2).double().mean()) >= 0.9
    )
    assert float(c[:, 0].median()) < 0.15
    # the hole is aimed at: the median pass is well inside it
    assert float(c[:, 1].median()) < 0.8
    ok = torch.stack([task.success(d, e) for d, e in zip(demos, envs)])
    assert 0.5 <= float(ok.double().mean()) <= 0.85
    # hand jitter: the path is not smooth at the sample scale (second differences are not ~0)
    d0 = demos[0]
    assert float((d0[2:] - 2 * d0[1:-1] + d0[:-2]).abs().max()) > 1e-3
    assert all(bool(torch.isfinite(d).all()) for d in demos)


def test_synthetic_demonstrator_reproducible_and_accepts_a_count():
    task = PointParticleTask(fixed_start=(0.5, 5.0))
    a, ea = task.demonstrations(4, 2, torch.Generator().manual_seed(3))
    b, eb = task.demonstrations(4, 2, torch.Generator().manual_seed(3))
    assert ea.shape == (8, 4)  # the task's environment dimension
    torch.testing.assert_close(ea, eb, rtol=0, atol=0)
    for x, y in zip(a, b):
        torch.testing.assert_close(x, y, rtol=0, atol=0)
    starts = torch.stack([d[0] for d in a])
    assert float((starts - torch.tensor([0.5, 5.0], dtype=F64)).norm(dim=-1).max()) < 0.5


@pytest.mark.slow
def test_pro_improves_demonstration_promps_on_the_task():
    """The task plugs into the batched optimiser: B environments at once, their environments
    broadcast against the samples with ``env[:, None]``."""
    from protorch import PRO, ProMP

    task = PointParticleTask()
    demos, envs = task.demonstrations(4, 3, torch.Generator().manual_seed(1))
    promps = [ProMP(2, 10, 100).fit(demos[3 * i : 3 * i + 3]) for i in range(4)]
    mean = torch.stack([p.mean for p in promps])  # (4, 20)
    var = torch.stack([p.var for p in promps]) + 1e-4  # (4, 20)
    env = envs[0::3]  # (4, 6)
    opt = PRO(mean, var, beta=20.0, num_samples=100, relevance_samples=100, max_iter=15, seed=0)
    res = opt.minimize(lambda w: task.costs(promps[0].trajectory(w), env[:, None]))
    before = task.costs(promps[0].trajectory(mean), env).sum(-1)  # (4,)
    after = task.costs(promps[0].trajectory(res.mean), env).sum(-1)  # (4,)
    assert bool((after < 0.5 * before).all())  # measured: 6 to 20 times lower after 15 iterations
    assert bool(task.success(promps[0].trajectory(res.mean), env).all())
