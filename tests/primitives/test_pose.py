"""Poses and pose ProMPs: q and -q are the same rotation wherever quaternions are compared,
interpolated, fitted or sampled; bad quaternions are refused with a clear error."""

from __future__ import annotations

import math

import pytest
import torch
from pytorch_kinematics.transforms import axis_angle_to_quaternion, quaternion_to_matrix

from protorch.primitives.pose import (
    PoseProMP,
    align_quaternions,
    check_unit_quaternion,
    normalize_poses,
    normalize_quaternion,
    quaternion_distance,
    quaternion_path_length,
    quaternion_slerp,
    resample_poses,
)

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def random_flip(q: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """``q (..., 4)`` with the sign of a random half of the quaternions flipped."""
    s = torch.where(torch.rand(q.shape[:-1], generator=gen, dtype=F64) < 0.5, -1.0, 1.0).to(q)
    return q * s[..., None]


def rotating_poses(angles: torch.Tensor, axis=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """A pose trajectory ``(T, 7)``: moving along x while turning by ``angles`` about ``axis``."""
    a = torch.tensor(axis, dtype=F64)
    q = axis_angle_to_quaternion(angles[:, None] * a / a.norm())  # (T, 4)
    zero = torch.zeros_like(angles)
    pos = torch.stack([torch.linspace(0, 1, len(angles), dtype=F64), zero, zero], -1)
    return torch.cat([pos, q], -1)


# ----------------------------------------------------------------------------- quaternions
def test_distance_is_the_rotation_angle_and_sign_invariant(gen):
    axes = torch.randn(50, 3, generator=gen, dtype=F64)
    angles = torch.rand(50, generator=gen, dtype=F64) * math.pi
    q1 = axis_angle_to_quaternion(torch.randn(50, 3, generator=gen, dtype=F64))
    rel = axis_angle_to_quaternion(axes / axes.norm(dim=-1, keepdim=True) * angles[:, None])
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = rel.unbind(-1)  # q2 = q1 * rel: the rotation angle between them is `angles`
    q2 = torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        -1,
    )
    d = quaternion_distance(q1, q2)
    torch.testing.assert_close(d, angles, atol=1e-10, rtol=0)
    torch.testing.assert_close(quaternion_distance(-q1, q2), d, atol=1e-12, rtol=0)
    torch.testing.assert_close(quaternion_distance(q1, -q2), d, atol=1e-12, rtol=0)
    assert float(quaternion_distance(q1, -q1).max()) < 1e-7  # the same rotation
    # exact near zero (where 2 acos |<q1, q2>| loses half its digits)
    tiny = axis_angle_to_quaternion(torch.tensor([1e-9, 0.0, 0.0], dtype=F64))
    assert (
        abs(float(quaternion_distance(torch.tensor([1.0, 0, 0, 0], dtype=F64), tiny)) - 1e-9)
        < 1e-18
    )
    # and the rotation matrices agree for q and -q
    torch.testing.assert_close(quaternion_to_matrix(q1), quaternion_to_matrix(-q1))


def test_align_makes_a_trajectory_sign_continuous_without_changing_rotations(gen):
    q = rotating_poses(torch.linspace(0, 3 * math.pi, 200, dtype=F64))[
        :, 3:
    ]  # turns 1.5 times: w changes sign
    flipped = random_flip(q, gen)
    aligned = align_quaternions(flipped, reference=q[0])
    torch.testing.assert_close(aligned, q)  # the smooth one back, first one in q[0]'s hemisphere
    assert float((aligned[1:] * aligned[:-1]).sum(-1).min()) > 0
    assert float(quaternion_distance(aligned, flipped).max()) < 1e-7
    # batched: one sign per sample
    batch = torch.stack([flipped, -flipped, q])
    torch.testing.assert_close(align_quaternions(batch, q[0]), q.expand(3, -1, -1))


def test_path_length_and_slerp(gen):
    q = rotating_poses(torch.linspace(0, 2.0, 101, dtype=F64), axis=(1.0, 2.0, 0.5))[:, 3:]
    torch.testing.assert_close(quaternion_path_length(q), torch.tensor(2.0, dtype=F64))
    torch.testing.assert_close(
        quaternion_path_length(random_flip(q, gen)), torch.tensor(2.0, dtype=F64)
    )
    t = torch.linspace(0, 1, 11, dtype=F64)
    s = quaternion_slerp(q[0], -q[-1], t)  # the other sign of the end: the same, shorter arc
    torch.testing.assert_close(quaternion_distance(s, q[0]), 2.0 * t, atol=1e-10, rtol=0)
    torch.testing.assert_close(s.norm(dim=-1), torch.ones(11, dtype=F64))
    same = quaternion_slerp(q[0], q[0], t)  # zero angle: no 0/0
    assert torch.isfinite(same).all()
    torch.testing.assert_close(same, q[0].expand(11, 4))


def test_resample_is_sign_invariant_and_interpolates_rotations(gen):
    traj = rotating_poses(torch.linspace(0, 1.5, 11, dtype=F64))
    flipped = torch.cat([traj[:, :3], random_flip(traj[:, 3:], gen)], -1)
    dense = resample_poses(flipped, 101)  # (101, 7)
    expected = rotating_poses(torch.linspace(0, 1.5, 101, dtype=F64))
    torch.testing.assert_close(dense[:, :3], expected[:, :3])
    assert float(quaternion_distance(dense[:, 3:], expected[:, 3:]).max()) < 1e-3  # nlerp ~ slerp
    torch.testing.assert_close(dense[:, 3:].norm(dim=-1), torch.ones(101, dtype=F64))


@pytest.mark.parametrize(
    "bad, message",
    [
        (torch.tensor([1.0, 0.0, float("nan"), 0.0]), "NaN"),
        (torch.zeros(4), "zero quaternion"),
        (torch.ones(3), "last dimension 4"),
    ],
)
def test_bad_quaternions_are_refused(bad, message):
    with pytest.raises(ValueError, match=message):
        normalize_quaternion(bad)


def test_unit_check_refuses_a_non_unit_quaternion():
    with pytest.raises(ValueError, match="unit quaternion.*1.0198"):
        check_unit_quaternion(torch.tensor([1.0, 0.0, 0.0, 0.2]), "start_quaternion", tol=1e-3)
    q = check_unit_quaternion(torch.tensor([0.7071068, 0.0, 0.0, 0.7071068]), tol=1e-6)
    assert abs(float(q.norm()) - 1) < 1e-12


@pytest.mark.parametrize("shape", [(10, 6), (10,), (3, 10, 8)])
def test_pose_trajectories_of_the_wrong_shape_are_refused(shape):
    with pytest.raises(ValueError, match=r"pose trajectory \(\.\.\., T, 7\)"):
        normalize_poses(torch.ones(shape))


# ----------------------------------------------------------------------------- pose ProMP
def _demos(gen, n=6):
    """Pose demonstrations: a turn of 60 to 120 degrees about z while moving, varying lengths."""
    demos = []
    for i in range(n):
        t = 60 + 10 * i
        angle = math.radians(60 + 60 * i / (n - 1))
        traj = rotating_poses(angle * torch.linspace(0, 1, t, dtype=F64) ** 2)
        traj[:, 1] += 0.05 * torch.randn((), generator=gen, dtype=F64)
        demos.append(traj)
    return demos


@pytest.mark.parametrize("device", DEVICES)
def test_pose_promp_fit_ignores_quaternion_signs(gen, device):
    demos = [d.to(device) for d in _demos(gen)]
    flipped = [
        torch.cat([d[:, :3], random_flip(d[:, 3:].cpu(), gen).to(device)], -1) for d in demos
    ]
    flipped[2] = torch.cat(
        [demos[2][:, :3], -demos[2][:, 3:]], -1
    )  # a whole demonstration flipped too
    ref = PoseProMP(8, 50, device=device).fit(demos)
    other = PoseProMP(8, 50, device=device).fit(flipped, reference=demos[0][0, 3:])
    torch.testing.assert_close(other.position.mean, ref.position.mean)
    torch.testing.assert_close(other.orientation.mean, ref.orientation.mean)
    torch.testing.assert_close(other.orientation.var, ref.orientation.var)
    # the opposite reference hemisphere gives the antipodal weights, the same rotations
    anti = PoseProMP(8, 50, device=device).fit(demos, reference=-demos[0][0, 3:])
    torch.testing.assert_close(anti.orientation.mean, -ref.orientation.mean)
    assert (
        float(
            quaternion_distance(anti.mean_trajectory()[:, 3:], ref.mean_trajectory()[:, 3:]).max()
        )
        < 1e-6
    )
    # the mean follows the demonstrations' average turn; its quaternions are unit and continuous
    mean = ref.mean_trajectory()  # (T, 7)
    torch.testing.assert_close(mean[:, 3:].norm(dim=-1), torch.ones(50, dtype=F64, device=device))
    end_angle = float(
        quaternion_distance(mean[-1, 3:], torch.tensor([1.0, 0, 0, 0], dtype=F64, device=device))
    )
    assert abs(end_angle - math.radians(90)) < math.radians(3)


def test_pose_promp_samples_are_unit_and_sign_continuous(gen):
    model = PoseProMP(8, 50).fit(_demos(gen))
    w_pos, w_rot = model.sample(64, generator=gen)
    traj = model.trajectory(w_pos, w_rot)  # (64, 50, 7)
    assert traj.shape == (64, 50, 7)
    torch.testing.assert_close(traj[..., 3:].norm(dim=-1), torch.ones(64, 50, dtype=F64))
    assert float((traj[..., 1:, 3:] * traj[..., :-1, 3:]).sum(-1).min()) > 0
    # std: (T, 7), the position part equals the position ProMP's own
    std = model.std_trajectory()
    assert std.shape == (50, 7)
    torch.testing.assert_close(std[:, :3], model.position.std_trajectory())


def test_pose_promp_refuses_bad_demonstrations(gen):
    demos = _demos(gen)
    bad = demos[1].clone()
    bad[5, 4] = float("nan")
    with pytest.raises(ValueError, match=r"demos\[1\] contains NaN"):
        PoseProMP(8, 50).fit([demos[0], bad])
    zero = demos[1].clone()
    zero[3, 3:] = 0
    with pytest.raises(ValueError, match=r"demos\[1\] quaternions contains a zero quaternion"):
        PoseProMP(8, 50).fit([demos[0], zero])
    with pytest.raises(ValueError, match=r"pose trajectory"):
        PoseProMP(8, 50).fit([d[:, :6] for d in demos])
