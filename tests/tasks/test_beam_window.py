"""The beam-through-a-window task (Sec. IV-A): collision on hand-made poses that pass and that
hit, via points computed from a rotated window, the objectives against hand-computed values,
q / -q invariance, input checks, and the simulated operator."""

from __future__ import annotations

import math

import pytest
import torch
from pytorch_kinematics.transforms import quaternion_raw_multiply, quaternion_to_matrix

from protorch.primitives.pose import quaternion_distance
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator, _jerk, quaternion_about

F64 = torch.float64
DEG = math.pi / 180
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

# An axis-aligned scene: the wall is the plane x = 0.5 (normal +x), the window 0.2 wide along y
# and 0.8 high along z around (0.5, 0, 0.5); wall 0.05 thick, beam 0.6 long with radius 0.015.
# Inflated by the radius: slab |x - 0.5| < 0.04, window |y| < 0.085, |z - 0.5| < 0.385.
Q_Y = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))  # beam along +y (horizontal)
PLAIN = dict(
    wall_position=(0.5, 0.0, 0.5),
    wall_quaternion=(1.0, 0.0, 0.0, 0.0),
    start_position=(0.0, 0.0, 0.5),
    start_quaternion=Q_Y,
    end_position=(1.0, 0.0, 0.5),
    end_quaternion=Q_Y,
)


def q_about(axis, deg):
    return quaternion_about(axis, deg * DEG)


def upright():
    """Beam along +z (q_x(90) q_z(90)), the task's passing orientation for an unrotated wall."""
    return quaternion_raw_multiply(q_about((1, 0, 0), 90), q_about((0, 0, 1), 90))


def pose(position, q):
    return torch.cat([torch.tensor(position, dtype=F64), torch.as_tensor(q, dtype=F64)])


@pytest.fixture
def task():
    return BeamWindowTask(**PLAIN)


# ----------------------------------------------------------------------------- collision
@pytest.mark.parametrize(
    "position, q, hits",
    [
        ((0.5, 0.0, 0.5), upright(), False),  # upright in the middle of the window
        ((0.5, 0.08, 0.5), upright(), False),  # 0.005 inside the inflated window edge
        ((0.5, 0.09, 0.5), upright(), True),  # 0.005 beyond it
        ((0.5, 0.0, 0.58), upright(), False),  # top end at 0.88 < 0.5 + 0.385
        ((0.5, 0.0, 0.59), upright(), True),  # top end at 0.89: in the wall above the window
        ((0.5, 0.0, 0.5), Q_Y, True),  # horizontal: 0.6 long in a 0.2 wide window
        (
            (0.55, 0.0, 0.5),
            Q_Y,
            False,
        ),  # horizontal, 0.05 in front of the wall plane (slab +- 0.04)
        ((0.535, 0.0, 0.5), Q_Y, True),  # horizontal, touching the inflated slab
        (
            (0.5, 0.0, 0.5),
            quaternion_raw_multiply(q_about((1, 0, 0), 10), upright()),
            False,
        ),  # 10 deg tilt: +-0.052
        (
            (0.5, 0.0, 0.5),
            quaternion_raw_multiply(q_about((1, 0, 0), 20), upright()),
            True,
        ),  # 20 deg: +-0.103
        (
            (0.5, 0.0, 0.5),
            (1.0, 0.0, 0.0, 0.0),
            False,
        ),  # along the normal: threaded through the centre
        (
            (0.5, 0.1, 0.5),
            (1.0, 0.0, 0.0, 0.0),
            True,
        ),  # along the normal, through the wall beside the window
        (
            (0.5, 0.0, 0.5),
            q_about((0, 0, 1), 45),
            False,
        ),  # 45 deg in x-y: inside the slab only |y| < 0.04
        ((0.5, 0.0, 0.5), q_about((0, 0, 1), 80), True),  # 80 deg: |y| up to 0.04 tan 80 = 0.23
        ((0.1, 0.0, 0.5), Q_Y, False),  # far in front
    ],
)
def test_collision_of_hand_made_poses(task, position, q, hits):
    p = pose(position, q)
    assert bool(task.collides_at(p)) is hits
    assert bool(task.collides_at(torch.cat([p[:3], -p[3:]]))) is hits  # -q: the same pose
    assert bool(task.collides_at(torch.cat([p[:3], 3 * p[3:]]))) is hits  # any norm: renormalised


@pytest.mark.parametrize("device", DEVICES)
def test_collision_is_batched_and_matches_a_dense_point_test(task, device, gen):
    poses = torch.cat(
        [
            0.5 + 0.06 * torch.randn(2000, 3, generator=gen, dtype=F64),
            torch.randn(2000, 4, generator=gen, dtype=F64),
        ],
        -1,
    )
    poses[:, 1] -= 0.5
    hit = task.collides_at(poses.to(device)).cpu()  # (2000,)
    # reference: 4001 points along each beam against the inflated wall
    q = poses[:, 3:] / poses[:, 3:].norm(dim=-1, keepdim=True)
    axis = quaternion_to_matrix(q)[:, :, 0]
    s = torch.linspace(-0.3, 0.3, 4001, dtype=F64)
    pts = poses[:, None, :3] + s[:, None] * axis[:, None]  # (2000, 4001, 3)
    in_slab = (pts[..., 0] - 0.5).abs() < 0.04
    in_window = (pts[..., 1].abs() < 0.085) & ((pts[..., 2] - 0.5).abs() < 0.385)
    ref = (in_slab & ~in_window).any(-1)
    assert 0.2 < ref.double().mean() < 0.8  # both kinds well represented
    assert int((hit != ref).sum()) <= 2  # only grazing contacts between the 4001 points may differ


def test_dense_resampling_catches_a_collision_between_samples(task):
    # two poses, horizontal, 0.2 before and after the wall: neither instant touches it
    traj = torch.stack([pose((0.3, 0.0, 0.5), Q_Y), pose((0.7, 0.0, 0.5), Q_Y)])
    assert not bool(task.collides(traj, substeps=1))
    assert bool(task.collides(traj))  # the default resampling puts a pose in the wall
    upright_traj = torch.stack(
        [pose((0.3, 0.0, 0.5), upright()), pose((0.7, 0.0, 0.5), -upright())]
    )
    assert not bool(
        task.collides(upright_traj, substeps=50)
    )  # -q at the end: no spurious half turn


# ----------------------------------------------------------------------------- via points
def test_via_points_of_the_unrotated_wall(task):
    start, front, back, end = task.via_poses()
    torch.testing.assert_close(front[:3], torch.tensor([0.35, 0.0, 0.5], dtype=F64))
    torch.testing.assert_close(back[:3], torch.tensor([0.65, 0.0, 0.5], dtype=F64))
    assert float(quaternion_distance(front[3:], upright())) < 1e-7
    torch.testing.assert_close(start, pose(PLAIN["start_position"], Q_Y))
    assert not bool(task.collides_at(torch.stack([start, front, back, end])).any())


def test_via_points_from_a_rotated_window(gen):
    """A wall at a random orientation: the window via points lie on its normal, the via
    orientation puts the beam along the window's height, and moving the whole scene by a rigid
    motion moves the via points with it."""
    rot = torch.randn(3, generator=gen, dtype=F64)
    q_wall = quaternion_about(rot, float(rot.norm()))
    r_wall = quaternion_to_matrix(q_wall)
    c = torch.tensor([0.2, -0.1, 0.7], dtype=F64)
    n = r_wall[:, 0]
    start, end = c - 0.6 * n + 0.1 * r_wall[:, 1], c + 0.5 * n - 0.05 * r_wall[:, 2]
    q_start = quaternion_raw_multiply(
        q_wall, q_about((0, 0, 1), 90)
    )  # parallel to the wall, horizontal
    ends = dict(
        start_position=start.tolist(),
        end_position=end.tolist(),
        start_quaternion=q_start.tolist(),
        end_quaternion=q_start.tolist(),
    )
    task = BeamWindowTask(wall_position=c.tolist(), wall_quaternion=q_wall.tolist(), **ends)
    _, front, back, _ = task.via_poses()
    torch.testing.assert_close(front[:3], c - 0.15 * n)  # on the start's side
    torch.testing.assert_close(back[:3], c + 0.15 * n)
    beam_axis = quaternion_to_matrix(front[3:])[:, 0]
    assert float(beam_axis @ r_wall[:, 2]) == pytest.approx(
        1.0, abs=1e-12
    )  # along the window's height
    # the same wall turned by 180 deg about its height: the normal flips, the via points do not move
    flipped = quaternion_raw_multiply(q_wall, q_about((0, 0, 1), 180))
    task2 = BeamWindowTask(wall_position=c.tolist(), wall_quaternion=flipped.tolist(), **ends)
    torch.testing.assert_close(task2.via_array()[1:3, :3], task.via_array()[1:3, :3])
    # a rigid motion of the whole scene (rotation g, translation t) moves the via poses with it
    g = quaternion_about(torch.tensor([0.3, -1.0, 0.4], dtype=F64), 1.1)
    r_g, t = quaternion_to_matrix(g), torch.tensor([1.0, 2.0, -0.5], dtype=F64)

    def moved(p, q):
        p, q = torch.as_tensor(p, dtype=F64), torch.as_tensor(q, dtype=F64)
        return (r_g @ p + t).tolist(), quaternion_raw_multiply(g, q).tolist()

    (mc, mq), (ms, mqs), (me, _) = moved(c, q_wall), moved(start, q_start), moved(end, q_start)
    task3 = BeamWindowTask(
        wall_position=mc,
        wall_quaternion=mq,
        start_position=ms,
        end_position=me,
        start_quaternion=mqs,
        end_quaternion=mqs,
    )
    for a, b in zip(task.via_poses(), task3.via_poses()):
        torch.testing.assert_close(r_g @ a[:3] + t, b[:3])
        assert float(quaternion_distance(quaternion_raw_multiply(g, a[3:]), b[3:])) < 1e-7


# ----------------------------------------------------------------------------- objectives
def test_position_costs_of_a_straight_line(task):
    """A line through the start, both window via points (on grid points) and the end: every
    distance is 0, the jerk of a line is 0, so each objective is 0.1 x its length, 1.0."""
    x = torch.linspace(0, 1, 101, dtype=F64)
    pos = torch.stack([x, torch.zeros_like(x), torch.full_like(x, 0.5)], -1)
    torch.testing.assert_close(
        task.position_costs(pos), torch.full((4,), 0.1, dtype=F64), atol=1e-12, rtol=0
    )
    shifted = pos + torch.tensor([0.0, 0.03, 0.04], dtype=F64)  # 0.05 off everywhere
    torch.testing.assert_close(
        task.position_costs(shifted), torch.full((4,), 0.05 + 0.1, dtype=F64)
    )
    batch = torch.stack([pos, shifted])[None]  # (1, 2, T, 3)
    assert task.position_costs(batch).shape == (1, 2, 4)


def test_jerk_is_the_third_difference_rescaled_to_jerk_steps():
    for t in (50, 200):
        z = torch.linspace(0, 1, t, dtype=F64)
        x = torch.stack([z**3, 2 * z**3], -1)  # x''' = (6, 12): Delta^3 = (6, 12) h^3
        per_step = _jerk(x)
        torch.testing.assert_close(
            per_step, torch.tensor(6 * math.sqrt(5) / (t - 1) ** 3, dtype=F64)
        )
        torch.testing.assert_close(
            _jerk(x, 1000), torch.tensor(6 * math.sqrt(5) / 999**3, dtype=F64)
        )


def test_orientation_costs_of_a_constant_upright_beam(task, gen):
    q = upright().expand(60, 4)
    phases = torch.tensor([0.0, 0.4, 0.6, 1.0], dtype=F64)
    c = task.orientation_costs(q, phases)
    torch.testing.assert_close(
        c, torch.tensor([math.pi / 2, 0, 0, math.pi / 2], dtype=F64), atol=1e-7, rtol=0
    )
    # q and -q at arbitrary steps, and any norm: the same costs, for a turning trajectory too
    turning = torch.stack(
        [
            quaternion_raw_multiply(q_about((1, 0, 0), a), torch.tensor(Q_Y, dtype=F64))
            for a in torch.linspace(0, 90, 60).tolist()
        ]
    )
    ref = task.orientation_costs(turning, phases)
    signs = torch.where(torch.rand(60, generator=gen, dtype=F64) < 0.5, -1.0, 1.0)
    torch.testing.assert_close(task.orientation_costs(2.0 * signs[:, None] * turning, phases), ref)
    # its length term: 0.1 x the 90 deg turned
    length = ref - quaternion_distance(
        turning[(phases * 59).round().long()], task.via_array()[:, 3:]
    )
    assert float(length[0]) == pytest.approx(0.1 * math.pi / 2, rel=1e-3)


def test_full_costs_are_invariant_to_quaternion_signs(task, gen):
    traj = torch.cat(
        [
            torch.randn(5, 40, 3, generator=gen, dtype=F64).cumsum(1) * 0.02,
            torch.randn(5, 40, 4, generator=gen, dtype=F64) * 0.05 + torch.tensor(Q_Y, dtype=F64),
        ],
        -1,
    )
    flipped = traj.clone()
    flipped[..., 3:] *= torch.where(torch.rand(5, 40, 1, generator=gen, dtype=F64) < 0.5, -1.0, 1.0)
    torch.testing.assert_close(task.costs(flipped), task.costs(traj))
    assert torch.equal(task.collides(flipped), task.collides(traj))
    assert torch.equal(task.success(flipped), task.success(traj))
    assert task.costs(traj).shape == (5, 8)


# ----------------------------------------------------------------------------- input checks
@pytest.mark.parametrize(
    "override, message",
    [
        (dict(start_quaternion=(1.0, 0.0, 0.0, 0.2)), "start_quaternion must be a unit quaternion"),
        (dict(wall_quaternion=(1.0, float("nan"), 0.0, 0.0)), "wall_quaternion contains NaN"),
        (dict(end_quaternion=(1.0, 0.0, 0.0)), "end_quaternion must be a quaternion"),
        (dict(wall_position=(0.5, 0.0)), "wall_position must have 3 numbers"),
        (dict(start_position=(0.0, float("inf"), 0.5)), "start_position contains inf"),
        (dict(beam_length=0.15), "must exceed window_width"),
        (dict(window_width=0.02), "larger than the beam's diameter"),
        (dict(end_position=(0.2, 0.0, 0.5)), "opposite sides of the wall"),
        (dict(window_height=0.5), r"pose\(s\) \['window_centre'\] put the beam inside the wall"),
        (
            dict(start_position=(0.49, 0.0, 0.5)),
            r"pose\(s\) \['start'\] put the beam inside the wall",
        ),
        (dict(collision_substeps=0), "collision_substeps must be an int >= 1"),
        (dict(beam_radius=-0.01), "beam_radius must be finite and >= 0"),
    ],
)
def test_bad_task_settings_are_refused(override, message):
    with pytest.raises(ValueError, match=message):
        BeamWindowTask(**{**PLAIN, **override})


def test_bad_trajectories_are_refused(task):
    good = torch.cat([torch.zeros(10, 3), torch.tensor(Q_Y).expand(10, 4)], -1).to(F64)
    with pytest.raises(ValueError, match=r"pose trajectory \(\.\.\., T, 7\)"):
        task.collides(good[:, :6])
    bad = good.clone()
    bad[4, 5] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        task.costs(bad)
    with pytest.raises(ValueError, match="NaN"):
        task.collides_at(bad)
    zero = good.clone()
    zero[2, 3:] = 0
    with pytest.raises(ValueError, match="zero quaternion"):
        task.collides(zero)
    with pytest.raises(ValueError, match="zero quaternion"):
        task.collides_at(zero)
    with pytest.raises(ValueError, match="zero quaternion"):
        task.orientation_costs(zero[:, 3:], [0.0, 0.4, 0.6, 1.0])
    with pytest.raises(ValueError, match=r"positions must be \(\.\.\., T, 3\)"):
        task.position_costs(good[:, :2])
    with pytest.raises(ValueError, match="phases must lie in"):
        task.orientation_costs(good[:, 3:], [0.0, 0.4, 1.6, 1.0])


# ----------------------------------------------------------------------------- operator
def test_an_operator_without_errors_always_succeeds(gen):
    task = BeamWindowTask()
    perfect = SimulatedOperator(
        depth_bias=0,
        depth_std=0,
        lateral_std=0,
        tilt_std=0,
        orientation_std=0,
        endpoint_std=0,
        endpoint_angle_std=0,
        jitter_std=0,
        jitter_angle_std=0,
    )
    trials = perfect.trials(task, 20, gen)
    assert all(bool(task.success(t)) for t in trials)


@pytest.mark.slow
def test_the_default_operator_mostly_fails_and_its_trials_are_valid_poses(gen):
    task = BeamWindowTask()
    op = SimulatedOperator()
    poses, lengths = op.intentions(task, 200, gen)
    rate = float(task.collides(poses).double().mean())
    assert 0.6 < rate < 0.95, rate  # about 0.79 (1000 trials)
    assert int(lengths.min()) >= op.lengths[0] and int(lengths.max()) <= op.lengths[1]
    torch.testing.assert_close(poses[..., 3:].norm(dim=-1), torch.ones(poses.shape[:2], dtype=F64))
    assert float((poses[:, 1:, 3:] * poses[:, :-1, 3:]).sum(-1).min()) > 0  # sign-continuous
    start = task.via_array()[0]
    assert float((poses[:, 0, :3] - start[:3]).norm(dim=-1).max()) < 0.06
    trials = op.trials(task, 3, gen)
    assert [t.shape[1] for t in trials] == [7, 7, 7] and all(
        op.lengths[0] <= len(t) <= op.lengths[1] for t in trials
    )


def test_bad_operator_settings_are_refused():
    with pytest.raises(ValueError, match="depth_std must be finite and >= 0"):
        SimulatedOperator(depth_std=-0.1)
    with pytest.raises(ValueError, match="turn_back must be"):
        SimulatedOperator(turn_back=(0.5, 1.5))
    with pytest.raises(ValueError, match="num must be an int >= 1"):
        SimulatedOperator().intentions(BeamWindowTask(), 0)
