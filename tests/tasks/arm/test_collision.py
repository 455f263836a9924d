"""The arm-reach task's collision models (protorch.tasks.arm.collision): the volume gap is exact
against dense sampling, the skeleton gap is the skeleton distance minus the radius, the volume
model is stricter than the skeleton, and the hand's volume objective follows the full frames."""

from __future__ import annotations

import pytest
import torch

from protorch.robots import ArmKinematics, capsule_segments
from protorch.tasks import ArmReachTask
from protorch.tasks.arm.collision import (
    capsules_clear,
    capsules_gap,
    end_volume_near,
    joints_clearance,
)
from protorch.tasks.arm.geometry import (
    point_cylinder_distance,
    segment_cylinder_distance,
    segment_cylinder_within,
)


def _sampled_gap(task, q, env):
    """Capsules against the can's solid cylinder by dense sampling: points every 0.25 mm along
    each capsule's segment, each point's closed-form distance to the cylinder, minus the radius."""
    a, b, r = capsule_segments(
        task.kinematics.frames(q), task.kinematics.frame_names, task.robot.capsule_list()
    )  # (T, C, 3)
    u = torch.linspace(0, 1, 1201, dtype=torch.float64)
    p = a[..., None, :] + u[:, None] * (b - a)[..., None, :]  # (T, C, U, 3)
    d = point_cylinder_distance(p, env[:2], task.can_radius, 0.0, task.can_height)  # (T, C, U)
    return float((d - r[:, None]).min())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_volume_gap_is_the_capsules_distance_to_the_can(seed):
    gen = torch.Generator().manual_seed(seed)
    task = ArmReachTask(collision="volume")
    q = task.start_config() + 0.3 * torch.randn(6, 7, generator=gen, dtype=torch.float64)
    env = task.sample_envs(1, gen)[0]
    gap = float(task.can_gap(q, env))
    assert gap == pytest.approx(_sampled_gap(task, q, env), abs=1e-6)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_pruned_volume_gap_equals_the_search_on_every_capsule_bit_for_bit(dtype):
    """capsules_gap searches only the capsules whose bounds allow the minimum: the same numbers as
    the golden-section search on all of them, near the can (many overlaps) and far from it; NaN in
    gives NaN out."""
    gen = torch.Generator().manual_seed(7)
    task = ArmReachTask(collision="volume")
    for scale in (0.15, 0.6):
        q = (
            task.start_config() + scale * torch.randn(40, 20, 7, generator=gen, dtype=torch.float64)
        ).to(dtype)
        env = task.sample_envs(40, gen, dtype=dtype)  # (40, 4)
        a, b, r = capsule_segments(
            task.kinematics.frames(q), task.kinematics.frame_names, task.robot.capsule_list()
        )  # (40, 20, C, 3)
        full = (
            segment_cylinder_distance(
                a, b, env[:, None, None, :2], task.can_radius, 0.0, task.can_height
            )
            - r
        )
        want = full.flatten(-2).amin(-1)  # (40,)
        assert torch.equal(capsules_gap(a, b, r, env, task.can_radius, task.can_height), want)
    a[3, 5, 2, 0] = float("nan")
    got = capsules_gap(a, b, r, env, task.can_radius, task.can_height)
    assert bool(got[3].isnan()) and not bool(got[:3].isnan().any())


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_many_trajectories_are_checked_in_pieces_with_the_numbers_of_one_call(dtype):
    """joints_clearance takes many trajectories a piece at a time (a multiple of 32 trajectories,
    the last piece shorter): the gaps and the table verdicts equal one call on all of them to the
    bit, for one batch dimension and for broadcast ones."""
    gen = torch.Generator().manual_seed(11)
    task = ArmReachTask(collision="volume")
    q = (
        task.start_config() + 0.4 * torch.randn(200, 20, 7, generator=gen, dtype=torch.float64)
    ).to(dtype)
    env = task.sample_envs(200, gen, dtype=dtype)  # (200, 4)
    whole = joints_clearance(task, q, env, chunk=None)
    got = joints_clearance(task, q, env, chunk=64 * 20)  # pieces of 64, 64, 64 and 8 trajectories
    assert (
        float(whole[0].amin()) < task.margin < float(whole[0].amax())
    )  # some touch the can, some clear it
    assert torch.equal(got[0], whole[0]) and torch.equal(got[1], whole[1])
    q4, env4 = q.view(5, 40, 20, 7), env.view(5, 40, 4)[:, :1]  # (5, 40, T, J), one can per row
    got4 = joints_clearance(task, q4, env4, chunk=64 * 20)
    assert got4[0].shape == (5, 40)
    assert torch.equal(got4[0], joints_clearance(task, q4, env4, chunk=None)[0])


@pytest.mark.parametrize("margin", [-0.02, 0.0, 0.01, 0.05])
def test_capsules_clear_is_the_gap_above_the_margin_verdict_for_verdict(margin):
    """capsules_clear decides by bounds where it can and searches the rest: the same verdict as
    capsules_gap > margin, near the can and far from it, including gaps at the margin itself."""
    gen = torch.Generator().manual_seed(11)
    task = ArmReachTask(collision="volume")
    for scale in (0.15, 0.6):
        q = task.start_config() + scale * torch.randn(60, 12, 7, generator=gen, dtype=torch.float64)
        env = task.sample_envs(60, gen)  # (60, 4)
        a, b, r = capsule_segments(
            task.kinematics.frames(q), task.kinematics.frame_names, task.robot.capsule_list()
        )  # (60, 12, C, 3)
        gap = capsules_gap(a, b, r, env, task.can_radius, task.can_height)  # (60,)
        for m in (margin, float(gap[0]), float(gap[1])):  # the margin, and gaps met exactly
            got = capsules_clear(a, b, r, env, task.can_radius, task.can_height, m)
            assert torch.equal(got, gap > m)
        assert 0 < int((gap > margin).sum()) < 60 or scale == 0.6


def test_capsules_clear_takes_one_margin_per_entry():
    """A tensor margin (one per batch entry, what the plan check's hysteresis passes) gives each
    entry the verdict of its own margin, the gaps met exactly included."""
    gen = torch.Generator().manual_seed(12)
    task = ArmReachTask(collision="volume")
    q = task.start_config() + 0.15 * torch.randn(3, 40, 12, 7, generator=gen, dtype=torch.float64)
    env = task.sample_envs(40, gen)  # (40, 4)
    a, b, r = capsule_segments(
        task.kinematics.frames(q), task.kinematics.frame_names, task.robot.capsule_list()
    )  # (3, 40, 12, C, 3)
    gap = capsules_gap(a, b, r, env, task.can_radius, task.can_height)  # (3, 40)
    margin = torch.stack(
        [
            torch.full((40,), 0.01, dtype=torch.float64),
            gap[1],  # exactly met: not clear
            0.03 * torch.rand(40, generator=gen, dtype=torch.float64),
        ]
    )  # (3, 40)
    got = capsules_clear(a, b, r, env, task.can_radius, task.can_height, margin)
    assert torch.equal(got, gap > margin)
    assert not bool(got[1].any())
    assert torch.equal(
        got[0], capsules_clear(a[0], b[0], r, env, task.can_radius, task.can_height, 0.01)
    )


@pytest.mark.parametrize("margin", [0.0, 0.01, 0.05])
def test_the_stopped_search_gives_the_full_searchs_verdict(margin):
    """segment_cylinder_within stops each segment once a point within the margin is found or
    convexity's bound clears it: the verdict of the full 40-step search, on segments around the
    can (slanted, vertical: a flat distance, horizontal), and at margins equal to the results."""
    gen = torch.Generator().manual_seed(5)
    n, radius, height = 20000, 0.0375, 0.23
    a = torch.rand(n, 3, generator=gen, dtype=torch.float64) * torch.tensor(
        [0.4, 0.4, 0.5]
    ) - torch.tensor([0.2, 0.2, 0.1])
    b = a + (torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5) * 0.3
    b[: n // 10, :2] = a[: n // 10, :2]
    b[n // 10 : n // 5, 2] = a[n // 10 : n // 5, 2]
    axis, r = (
        torch.zeros(n, 2, dtype=torch.float64),
        0.06 * torch.rand(n, generator=gen, dtype=torch.float64),
    )
    full = segment_cylinder_distance(a, b, axis, radius, 0.0, height) - r  # (n,)
    got = segment_cylinder_within(a, b, axis, radius, 0.0, height, r, margin)
    assert torch.equal(got, full <= margin)
    assert 0 < int(got.sum()) < n
    for i in range(40):  # each margin met exactly: the search's own value decides
        one = segment_cylinder_within(
            a[i : i + 1],
            b[i : i + 1],
            axis[i : i + 1],
            radius,
            0.0,
            height,
            r[i : i + 1],
            float(full[i]),
        )
        assert bool(one[0])
        assert not bool(
            segment_cylinder_within(
                a[i : i + 1],
                b[i : i + 1],
                axis[i : i + 1],
                radius,
                0.0,
                height,
                r[i : i + 1],
                float(full[i]) - 1e-6,
            )[0]
        )


def test_point_and_segment_cylinder_distances_over_the_top_beside_and_through_the_can():
    axis = torch.tensor([0.5, 0.0], dtype=torch.float64)
    pts = torch.tensor(
        [[0.5, 0.0, 0.33], [0.6, 0.0, 0.1], [0.6, 0.0, 0.33], [0.51, 0.0, 0.2]], dtype=torch.float64
    )
    d = point_cylinder_distance(pts, axis, 0.0375, 0.0, 0.23)
    expect = [
        0.1,
        0.0625,
        (0.0625**2 + 0.1**2) ** 0.5,
        -0.0275,
    ]  # over the top, beside, the rim, inside (the wall)
    assert torch.allclose(d, torch.tensor(expect, dtype=torch.float64), atol=1e-12)
    seg = torch.tensor(
        [[0.3, 0.0, 0.30], [0.7, 0.0, 0.30]], dtype=torch.float64
    )  # 7 cm over the flat top
    assert float(
        segment_cylinder_distance(seg[0], seg[1], axis, 0.0375, 0.0, 0.23)
    ) == pytest.approx(0.07, abs=1e-8)
    through = torch.tensor(
        [[0.3, 0.01, 0.10], [0.7, 0.01, 0.10]], dtype=torch.float64
    )  # through the middle
    depth = float(segment_cylinder_distance(through[0], through[1], axis, 0.0375, 0.0, 0.23))
    assert depth == pytest.approx(-(0.0375 - 0.01), abs=1e-8)
    beside = torch.tensor(
        [[0.3, 0.1, 0.0], [0.7, 0.1, 0.2]], dtype=torch.float64
    )  # a slanted pass beside
    assert float(
        segment_cylinder_distance(beside[0], beside[1], axis, 0.0375, 0.0, 0.23)
    ) == pytest.approx(0.1 - 0.0375, abs=1e-8)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_volume_objective_takes_the_joints_cos_and_sin_once(gen, dtype):
    """end_volume_near computes the joints' cos/sin rows once and hands them to each frame's
    capsules: the same numbers to the bit as each frame computing its own (the code before), and
    the rows handed over are used (wrong rows give other numbers)."""

    class PerFrame(ArmKinematics):  # ignores the rows handed over: each call computes its own
        def ee_frame_rows(self, q, trig=None):
            return super().ee_frame_rows(q)

        def carry_points_rows(self, q, plan, *, functional=False, trig=None):
            return super().carry_points_rows(q, plan, functional=functional)

    task = ArmReachTask(can_objective="volume")
    kin = task.kinematics
    assert len(task.end_capsules) >= 2  # frames: the end link's and another (the sharing matters)
    per_frame = PerFrame(kin.urdf_text, end_link=kin.end_link)
    traj = (
        task.start_config() + 0.4 * torch.randn(30, 25, 7, generator=gen, dtype=torch.float64)
    ).to(dtype)
    env = task.sample_envs(30, gen).to(dtype)
    near, path = end_volume_near(kin, traj, env, task.end_capsules, task.can_height)
    near0, path0 = end_volume_near(per_frame, traj, env, task.end_capsules, task.can_height)
    assert torch.equal(near, near0) and torch.equal(path, path0)
    plan = next(caps for frame, caps in task.end_capsules.items() if frame is not None)[0]
    c, s = kin.trig_rows(traj[:, ::2])
    x = kin.carry_points_rows(traj[:, ::2], plan, trig=(s, c))[0]
    assert not torch.equal(x, kin.carry_points_rows(traj[:, ::2], plan)[0])


def test_skeleton_gap_and_the_stricter_volume_model():
    skel, vol = ArmReachTask(), ArmReachTask(collision="volume")
    q = skel.start_config()[None].expand(3, 7)
    env = skel.sample_envs(20, torch.Generator().manual_seed(3))
    g_s = skel.can_gap(q[None].expand(20, 3, 7), env)
    assert torch.allclose(g_s, skel.can_distance(q[None].expand(20, 3, 7), env) - skel.can_radius)
    g_v = vol.can_gap(q[None].expand(20, 3, 7), env)
    assert bool((g_v < g_s).all())  # the link capsules stick out of the skeleton everywhere


def test_the_volume_objective_reads_the_hand_and_forearm_capsules(gen):
    task = ArmReachTask(can_objective="volume")
    q = task.start_config() + 0.3 * torch.randn(5, 7, generator=gen, dtype=torch.float64)
    env = task.sample_envs(1, gen)[0]
    near, path = end_volume_near(
        task.kinematics, q[:, None], env, task.end_capsules, task.can_height
    )  # (5, 1)
    near = near[:, 0]
    assert torch.allclose(path[:, 0], task.kinematics.ee_position(q), atol=1e-12)
    traj = q[None]  # one trajectory of 5 steps: the distance at every other step
    assert end_volume_near(task.kinematics, traj, env, task.end_capsules, task.can_height)[
        0
    ].shape == (1, 3)
    # the same capsules placed by the full chain, their distance to the can's axis segment by
    # sampling
    capsules = task.robot.capsule_list()
    a, b, r = capsule_segments(task.kinematics.frames(q), task.kinematics.frame_names, capsules)
    keep = torch.tensor(
        [c.link in ("panda_link5", "panda_link7", "panda_link8", "panda_hand") for c in capsules]
    )
    a, b, r = a[:, keep], b[:, keep], r[keep]
    u = torch.linspace(0, 1, 2001, dtype=torch.float64)
    p = a[..., None, :] + u[:, None] * (b - a)[..., None, :]  # (5, C, U, 3)
    axis = torch.cat(
        [
            env[:2].expand(2001, 2),
            torch.linspace(0, task.can_height, 2001, dtype=torch.float64)[:, None],
        ],
        1,
    )
    d = torch.cdist(p.reshape(5, -1, 3), axis[None]).amin(-1).reshape(p.shape[:-1])  # (5, C, U)
    ref = (d.amin(-1) - r).amin(-1)
    assert bool(
        (near >= ref - 2e-4).all()
    )  # never nearer than the exact distance (a stand-in over the top)
    assert float((near - ref).max()) < 0.03
    # the can objective now reads those capsules, not the tool centre point
    plain = ArmReachTask()
    assert not torch.allclose(task.costs(q[None], env)[..., 1], plain.costs(q[None], env)[..., 1])


def test_bad_collision_settings_are_refused():
    with pytest.raises(ValueError, match="collision must be one of skeleton, volume"):
        ArmReachTask(collision="mesh")
    with pytest.raises(ValueError, match="can_objective must be one of ee, volume, skeleton, auto"):
        ArmReachTask(can_objective="hand")
    assert (
        ArmReachTask().can_objective == "ee"
        and ArmReachTask(collision="volume").can_objective == "volume"
    )
    assert ArmReachTask().margin == 0.02 and ArmReachTask(collision="volume").margin == 0.01
    assert ArmReachTask(collision="volume", can_objective="ee").can_objective == "ee"


def test_the_skeleton_objective_reads_what_the_skeleton_check_reads(gen):
    """can = clearance - min(distance of the skeleton to the can's axis over the cost steps,
    clearance) + d; start and goal are the end effector's, as with the paper's objective."""
    task, paper = ArmReachTask(can_objective="skeleton"), ArmReachTask()
    q = task.start_config() + 0.3 * torch.randn(
        4, 100, 7, generator=gen, dtype=torch.float64
    )  # (4, T, 7)
    env = task.sample_envs(4, gen)
    c, c_ee = task.costs(q, env), paper.costs(q, env)  # (4, 3)
    idx = task.cost_indices(100)
    near = task.can_distance(
        q[:, idx], env
    )  # the success check's skeleton distance, before the radius
    dev = c_ee[:, 1] - (
        task.clearance - _ee_near(task, q[:, idx], env).clamp(max=task.clearance)
    )  # d, (4,)
    expected = task.clearance - near.clamp(max=task.clearance) + dev
    assert torch.allclose(c[:, 1], expected, atol=1e-12)
    assert torch.allclose(c[:, [0, 2]], c_ee[:, [0, 2]], atol=1e-12)


def _ee_near(task, q, env):
    """The paper's distance: the end effector's horizontal distance to the can's axis, min over
    steps."""
    return (task.ee_path(q)[..., :2] - env[..., None, 0:2]).norm(dim=-1).amin(-1)


@pytest.mark.parametrize("can_objective", ["ee", "volume", "skeleton"])
def test_one_objective_alone_equals_its_column_of_the_costs(can_objective, gen):
    task = ArmReachTask(can_objective=can_objective)
    q = task.start_config() + 0.2 * torch.randn(3, 100, 7, generator=gen, dtype=torch.float64)
    env = task.sample_envs(3, gen)
    c = task.costs(q, env)
    for i in range(3):
        assert torch.equal(task.objective_cost(q, env, i), c[..., i])
    with pytest.raises(ValueError, match="index must be 0, 1 or 2"):
        task.objective_cost(q, env, 3)
