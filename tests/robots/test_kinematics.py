"""The arm's kinematics (protorch.robots.kinematics, protorch.robots): the shipped Panda URDF
against an
independent Denavit-Hartenberg computation, batched shapes, the compiled end-effector path, the
Jacobian, damped-least-squares IK, and clear errors for bad URDFs and joint tensors."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.robots import load_robot
from protorch.robots.kinematics import ArmKinematics
from tests.benchmarks import benchmark_module

F64 = torch.float64
PANDA = load_robot("panda")
PANDA_URDF = PANDA.urdf
PANDA_LIMITS = tuple(zip(PANDA.lower, PANDA.upper))
PANDA_MAX_VELOCITY = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)  # rad/s, Franka's data sheet
with benchmark_module(
    "replay_physics.py", "_replay_physics"
) as _replay:  # the independent DH model
    PANDA_DH, PANDA_FLANGE, PANDA_TCP = _replay.PANDA_DH, _replay.PANDA_FLANGE, _replay.PANDA_TCP


@pytest.fixture(scope="module")
def kin():
    return ArmKinematics()


def dh_frames(q: torch.Tensor) -> torch.Tensor:
    """Independent reference: Craig's modified DH, ``T_i = RotX(alpha) TransX(a) RotZ(q)
    TransZ(d)``,
    then the flange, the hand's yaw and the TCP offset. ``q (P, 7) -> (P, 11, 4, 4)`` (base
    first)."""

    def rot_x(a):
        c, s = math.cos(a), math.sin(a)
        return torch.tensor([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=F64)

    def trans(x, y, z):
        m = torch.eye(4, dtype=F64)
        m[:3, 3] = torch.tensor([x, y, z], dtype=F64)
        return m

    def rot_z(t):  # (P,) -> (P, 4, 4)
        m = torch.eye(4, dtype=F64).repeat(t.shape[0], 1, 1)
        m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = t.cos(), -t.sin(), t.sin(), t.cos()
        return m

    p = q.shape[0]
    out = [torch.eye(4, dtype=F64).repeat(p, 1, 1)]
    for i, (a, d, alpha) in enumerate(PANDA_DH):
        out.append(out[-1] @ rot_x(alpha) @ trans(a, 0, 0) @ rot_z(q[:, i]) @ trans(0, 0, d))
    out.append(out[-1] @ trans(0, 0, PANDA_FLANGE))  # link8, the flange
    yaw, tcp = PANDA_TCP
    out.append(out[-1] @ rot_z(torch.full((p,), yaw, dtype=F64)))  # the hand
    out.append(out[-1] @ trans(0, 0, tcp))  # the tool centre point
    return torch.stack(out, 1)  # (P, 11, 4, 4)


def random_q(n: int, gen: torch.Generator) -> torch.Tensor:
    lo, hi = torch.tensor(PANDA_LIMITS, dtype=F64).T
    return lo + (hi - lo) * torch.rand(n, 7, generator=gen, dtype=F64)


def test_urdf_matches_an_independent_dh_computation(kin, gen):
    q = random_q(200, gen)
    ours = kin.frames(q)  # (200, 11, 4, 4)
    ref = dh_frames(q)
    assert ours.shape == (200, 11, 4, 4) and kin.frame_names[0] == "panda_link0"
    assert kin.frame_names[-1] == "panda_hand_tcp"
    # URDF offsets are parsed in float32 by pytorch_kinematics: agreement to ~1e-7 m
    assert torch.allclose(ours, ref, atol=2e-6), float((ours - ref).abs().max())


def test_zero_configuration_is_the_known_panda_pose(kin):
    pos = kin.link_positions(torch.zeros(7, dtype=F64))  # (11, 3)
    assert torch.allclose(
        pos[8], torch.tensor([0.088, 0.0, 0.926], dtype=F64), atol=1e-6
    )  # the flange
    assert torch.allclose(pos[-1], torch.tensor([0.088, 0.0, 0.926 - 0.1034], dtype=F64), atol=1e-6)


def test_limits_come_from_the_urdf(kin):
    lo, hi = torch.tensor(PANDA_LIMITS, dtype=F64).T
    assert torch.equal(kin.lower, lo) and torch.equal(kin.upper, hi)
    assert torch.equal(kin.max_velocity, torch.tensor(PANDA_MAX_VELOCITY, dtype=F64))
    assert kin.joint_names == [f"panda_joint{i}" for i in range(1, 8)]
    inside = (lo + hi) / 2
    assert bool(kin.within_limits(inside)) and not bool(
        kin.within_limits(inside + torch.eye(7, dtype=F64)[3] * 3)
    )


def test_batched_fk_of_sample_by_time_tensors_in_one_call(kin, gen):
    q = random_q(4 * 6, gen).reshape(4, 6, 7)  # (S, T, 7)
    frames = kin.frames(q)
    assert frames.shape == (4, 6, 11, 4, 4)
    assert torch.allclose(frames[2, 3], kin.frames(q[2, 3]), atol=1e-12)
    assert kin.link_positions(q).shape == (4, 6, 11, 3) and kin.ee_position(q).shape == (4, 6, 3)


@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-9), (torch.float32, 2e-5)])
def test_compiled_ee_path_equals_pytorch_kinematics(kin, gen, dtype, atol):
    q = random_q(500, gen).reshape(5, 100, 7)
    ref = kin.link_positions(q)[..., -1, :]  # (5, 100, 3)
    fast = kin.ee_position(q.to(dtype))
    assert fast.dtype == dtype and torch.allclose(fast.double(), ref, atol=atol)


@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-9), (torch.float32, 2e-5)])
def test_compiled_skeleton_equals_pytorch_kinematics(kin, gen, dtype, atol):
    q = random_q(300, gen).reshape(3, 100, 7)
    ref = kin.link_positions(q)  # (3, 100, 11, 3)
    fast = kin.skeleton(q.to(dtype))
    assert (
        fast.shape == ref.shape
        and fast.dtype == dtype
        and torch.allclose(fast.double(), ref, atol=atol)
    )
    assert torch.equal(kin.skeleton(q[0, 0]), kin.skeleton(q)[0, 0])  # unbatched, one configuration


def test_compiled_path_folds_any_joint_axis(tmp_path, gen):
    urdf = """<robot name="toy">
      <link name="base"/><link name="l1"/><link name="l2"/><link name="tip"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
        <origin xyz="0 0 0.3" rpy="0.2 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
      <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
        <origin xyz="0.4 0 0" rpy="0 0.3 0.1"/><axis xyz="1 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
      <joint name="fix" type="fixed"><parent link="l2"/><child link="tip"/><origin xyz="0.25 0.05 0"/></joint>
    </robot>"""
    path = tmp_path / "toy.urdf"
    path.write_text(urdf)
    toy = ArmKinematics(path, end_link="tip")
    q = 6 * torch.rand(300, 2, generator=gen, dtype=F64) - 3
    assert torch.allclose(toy.ee_position(q), toy.link_positions(q)[:, -1], atol=1e-6)
    assert torch.allclose(toy.skeleton(q), toy.link_positions(q), atol=1e-6)
    assert (
        toy.num_joints == 2 and ArmKinematics(urdf, end_link="tip").num_frames == 4
    )  # the XML text works too


def test_jacobian_matches_finite_differences(kin, gen):
    q = random_q(3, gen)
    jac = kin.jacobian(q)  # (3, 6, 7)
    eps = 1e-6
    num = torch.stack(
        [
            (kin.ee_position(q + eps * e) - kin.ee_position(q - eps * e)) / (2 * eps)
            for e in torch.eye(7, dtype=F64)
        ],
        -1,
    )  # (3, 3, 7)
    assert torch.allclose(jac[:, :3], num, atol=1e-5)


def test_damped_least_squares_ik_reaches_a_pose_within_limits(kin, gen):
    q0 = torch.tensor([0, -0.785, 0, -2.356, 0, 1.571, 0.785], dtype=F64).expand(16, 7)  # "ready"
    q_true = q0 + 0.8 * (
        torch.rand(16, 7, generator=gen, dtype=F64) - 0.5
    )  # poses around it (a local method)
    pose = kin.ee_pose(q_true)
    q, err = kin.inverse(pose[:, :3, 3], q0, rotation=pose[:, :3, :3], iters=300)
    got = kin.ee_pose(q)
    assert float(err.max()) < 1e-4 and torch.allclose(got[:, :3, 3], pose[:, :3, 3], atol=1e-4)
    assert torch.allclose(got[:, :3, :3], pose[:, :3, :3], atol=1e-3)
    assert bool(kin.within_limits(q).all())


def test_module_to_moves_the_chain(kin):
    k32 = ArmKinematics().to(torch.float32)
    assert k32.lower.dtype == torch.float32 and k32.chain.dtype == torch.float32
    assert k32.frames(torch.zeros(2, 7)).dtype == torch.float32


# ----------------------------------------------------------------------------- bad input
def test_urdf_without_the_end_link_is_refused():
    with pytest.raises(ValueError, match="no link named 'gripper_tip'.*end_link"):
        ArmKinematics(end_link="gripper_tip")
    text = PANDA_URDF.read_text().replace('name="panda_hand_tcp"', 'name="tcp"')
    with pytest.raises(ValueError, match="panda_hand_tcp"):
        ArmKinematics(text)


def test_bad_urdf_files_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="no URDF file"):
        ArmKinematics(tmp_path / "missing.urdf")
    with pytest.raises(ValueError, match="not valid XML"):
        ArmKinematics("<robot><link name='a'></robot>")
    with pytest.raises(ValueError, match="not a URDF"):
        ArmKinematics("<sdf><link name='a'/></sdf>", end_link="a")
    with pytest.raises(
        ValueError, match="could not be read by pytorch_kinematics"
    ):  # <limit> without effort
        ArmKinematics(
            """<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="revolute">
          <parent link="a"/><child link="b"/><limit lower="0" upper="1"/></joint></robot>""",
            end_link="b",
        )
    prismatic = """<robot name="p"><link name="a"/><link name="b"/>
      <joint name="j" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>
      <limit lower="0" upper="1" effort="1" velocity="1"/></joint></robot>"""
    with pytest.raises(ValueError, match="only revolute and fixed"):
        ArmKinematics(prismatic, end_link="b")


@pytest.mark.parametrize("shape", [(7,), (3, 7), (2, 5, 7)])
def test_right_joint_count_any_batch(kin, shape):
    assert kin.link_positions(torch.zeros(shape, dtype=F64)).shape == (*shape[:-1], 11, 3)


@pytest.mark.parametrize("bad", [torch.zeros(3, 6), torch.zeros(2, 5, 8), torch.zeros(())])
def test_wrong_number_of_joints_is_refused(kin, bad):
    for fn in (kin.frames, kin.ee_position, kin.jacobian, kin.within_limits):
        with pytest.raises(ValueError, match="7 joints|dimensions"):
            fn(bad)
    with pytest.raises(ValueError, match="NaN"):
        kin.frames(torch.full((7,), float("nan")))
    assert bool(
        kin.ee_position(torch.full((7,), float("nan"))).isnan().all()
    )  # the unchecked hot path


def test_compiled_end_frame_equals_the_full_chain(kin, gen):
    lo, hi = torch.tensor(PANDA_LIMITS, dtype=F64).T
    q = lo + (hi - lo) * torch.rand(3, 5, 7, generator=gen, dtype=F64)
    full = kin.frames(q)[..., -1, :, :]  # (3, 5, 4, 4)
    fast = kin.ee_frame(q)
    assert fast.shape == (3, 5, 4, 4)
    assert torch.allclose(fast, full, atol=1e-12)
    assert torch.allclose(kin.ee_frame(q.float()), full.float(), atol=1e-5)


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_carried_points_equal_the_full_chains_frames(robot, gen):
    """carry_points places points fixed on any links (given in any order) as the full chain's
    frames place them: the capsules' ends of two arms, float64 and float32, any batch shape."""
    from protorch.robots import capsule_segments

    desc = load_robot(robot)
    k = desc.kinematics()
    caps = desc.capsule_list()
    links = [c.link for c in caps]
    plan = k.point_plan(
        links + links, torch.tensor([c.a for c in caps] + [c.b for c in caps], dtype=F64)
    )
    q = torch.tensor(desc.home, dtype=F64) + 0.5 * torch.randn(
        4, 6, k.num_joints, generator=gen, dtype=F64
    )
    a, b, _ = capsule_segments(k.frames(q), k.frame_names, caps)  # (4, 6, C, 3)
    ends = k.carry_points(q, plan)  # (4, 6, 2C, 3)
    assert ends.shape == (4, 6, 2 * len(caps), 3)
    tol = (
        1e-12 if robot == "panda" else 1e-6
    )  # the iiwa's URDF angles are snapped to within 1e-7 (module docstring)
    assert torch.allclose(ends, torch.cat([a, b], -2), atol=tol)
    assert torch.allclose(k.carry_points(q.float(), plan).double(), ends, atol=2e-5)
    x, y, z = k.carry_points_rows(q, plan)  # (2C, P) component-major
    assert torch.equal(torch.stack([x, y, z], -1).transpose(0, 1).reshape(ends.shape), ends)
    # the functional path (torch.cat, nothing written in place: what AOTInductor compiles) to the
    # bit
    assert torch.equal(k.carry_points(q, plan, functional=True), ends)
    assert torch.equal(
        k.carry_points(q.float(), plan, functional=True), k.carry_points(q.float(), plan)
    )
    with pytest.raises(ValueError, match="no frame 'nope'"):
        k.point_plan(["nope"], torch.zeros(1, 3))
    with pytest.raises(ValueError, match=r"points must be \(2, 3\)"):
        k.point_plan(links[:2], torch.zeros(3, 3))


@pytest.mark.parametrize("robot", ["panda", "iiwa14"])
def test_compiled_jacobian_and_pose_equal_pytorch_kinematics(robot, gen):
    desc = load_robot(robot)
    k = desc.kinematics()
    q = torch.tensor(desc.home, dtype=F64) + 0.7 * torch.randn(
        50, k.num_joints, generator=gen, dtype=F64
    )
    jac, pose = k.jacobian_pose(q)  # (50, 6, J), (50, 4, 4)
    tol = 1e-12 if robot == "panda" else 1e-6
    assert torch.allclose(jac, k.jacobian(q), atol=tol)
    assert torch.allclose(pose, k.frames(q)[:, -1], atol=tol)
    ik_chain, _ = k.inverse(pose[:5, :3, 3] + 0.02, q[:5], rotation=pose[:5, :3, :3])
    ik_fast, _ = k.inverse(pose[:5, :3, 3] + 0.02, q[:5], rotation=pose[:5, :3, :3], compiled=True)
    assert torch.allclose(ik_fast, ik_chain, atol=1e-6)  # the IK follows the same steps
