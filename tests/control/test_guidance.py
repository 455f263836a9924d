"""Haptic guidance: the stiffness law (inversely proportional to the ProMP's std, clipped), the
force's direction and size, q / -q invariance, and the simulated assisted operator's balance."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.control.guidance import HapticGuidance, guidance_force, stiffness_law
from protorch.primitives.pose import PoseProMP, quaternion_distance
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(scope="module")
def promp():
    """A pose ProMP fitted to 10 simulated trials (wide in the middle, narrower at the ends)."""
    task = BeamWindowTask()
    trials = SimulatedOperator().trials(task, 10, torch.Generator().manual_seed(0))
    return PoseProMP(10, 100).fit(trials, reference=torch.tensor(task.start_quaternion, dtype=F64))


def test_stiffness_is_inversely_proportional_to_the_std_within_the_clip():
    std = torch.tensor([1e-4, 1e-3, 0.01, 0.02, 0.05, 0.1, 1.0, 0.0], dtype=F64)
    k = stiffness_law(std, gain=30.0, k_max=3000.0, k_min=100.0)
    inside = (30.0 / std > 100.0) & (30.0 / std < 3000.0)
    torch.testing.assert_close(
        k[inside] * std[inside], torch.full((int(inside.sum()),), 30.0, dtype=F64)
    )
    assert inside.sum() == 3  # 0.02, 0.05, 0.1: K = 1500, 600, 300
    torch.testing.assert_close(
        k[:3], torch.full((3,), 3000.0, dtype=F64)
    )  # small std (and 0.01 exactly): k_max
    assert float(k[6]) == 100.0  # wide: k_min
    assert float(k[7]) == 3000.0  # zero std: k_max, not inf or NaN
    # halving the std doubles the stiffness (inside the clip)
    ratio = stiffness_law(torch.tensor(0.025), 30.0, 3000.0) / stiffness_law(
        torch.tensor(0.05), 30.0, 3000.0
    )
    assert float(ratio) == pytest.approx(2.0)


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(gain=-1.0, k_max=1.0), "gain must be >= 0"),
        (dict(gain=1.0, k_max=1.0, k_min=2.0), "k_min must be <= k_max"),
    ],
)
def test_bad_stiffness_settings_are_refused(kw, message):
    with pytest.raises(ValueError, match=message):
        stiffness_law(torch.ones(3), **kw)
    with pytest.raises(ValueError, match="std must be >= 0"):
        stiffness_law(-torch.ones(3), gain=1.0, k_max=1.0)


def test_guidance_settings_are_checked():
    with pytest.raises(ValueError, match="position_min .* must be <= position_max"):
        HapticGuidance.check_settings(position_min=10.0, position_max=5.0)
    with pytest.raises(ValueError, match="rotation_gain must be finite and >= 0"):
        HapticGuidance.check_settings(rotation_gain=float("nan"))
    with pytest.raises(ValueError, match="unknown guidance setting"):
        HapticGuidance.check_settings(stiffness=3.0)


def test_force_points_from_the_device_to_the_mean_with_size_k_times_distance(promp):
    guide = HapticGuidance(promp)
    z = torch.linspace(0, 1, 7, dtype=F64)
    mu = promp.mean_trajectory()[(z * 99).round().long()]  # (7, 7)
    offset = torch.tensor([0.03, -0.02, 0.01], dtype=F64)
    x = mu.clone()
    x[:, :3] += offset
    f = guide.force(z, x)  # (7, 7)
    k = guide.stiffness_at(z)
    torch.testing.assert_close(f[:, :3], -k[:, :3] * offset)  # towards the mean, per coordinate
    assert (f[:, :3] @ offset < 0).all()  # restoring
    torch.testing.assert_close(f[:, 3:], torch.zeros(7, 4, dtype=F64))  # the orientation is right
    torch.testing.assert_close(guide.force(z, mu), torch.zeros(7, 7, dtype=F64))
    # a rotation error: the quaternion force reduces it; -q feels the same force
    x2 = mu.clone()
    x2[:, 3:] = torch.nn.functional.normalize(
        mu[:, 3:] + 0.1 * torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=F64), dim=-1
    )
    f2 = guide.force(z, x2)
    x3 = x2.clone()
    x3[:, 3:] = -x3[:, 3:]
    torch.testing.assert_close(guide.force(z, x3), f2)
    stepped = torch.nn.functional.normalize(x2[:, 3:] + 1e-3 * f2[:, 3:] / k[:, 3:], dim=-1)
    assert (
        quaternion_distance(stepped, mu[:, 3:]) < quaternion_distance(x2[:, 3:], mu[:, 3:])
    ).all()
    # the functional form: F = K (mu - x)
    torch.testing.assert_close(
        guidance_force(torch.full((7,), 2.0, dtype=F64), mu[0], x[0])[:3], -2.0 * offset
    )


def test_stiffness_follows_the_promps_std_over_the_phase(promp):
    guide = HapticGuidance(promp, position_gain=30.0, position_max=1e9)
    std = promp.std_trajectory()
    torch.testing.assert_close(guide.stiffness[:, :3], 30.0 / std[:, :3])
    wide, narrow = int(std[:, 0].argmax()), int(std[:, 0].argmin())
    assert float(guide.stiffness[wide, 0]) < float(guide.stiffness[narrow, 0])


@pytest.mark.parametrize("device", DEVICES)
def test_assisted_device_balances_hand_and_fixture(promp, device, gen):
    task = BeamWindowTask()
    intended, lengths = SimulatedOperator().intentions(task, 8, gen)
    intended, model = intended.to(device), promp.copy().to(device)
    guide = HapticGuidance(model)
    k_h = 300.0
    res = guide.assist(
        intended, lengths=lengths, human_position_stiffness=k_h, human_rotation_stiffness=3.0
    )
    assert res.poses.shape == intended.shape and res.poses.device.type == device
    idx = res.phase_index  # (B, T): the clock over each trial
    t = torch.arange(intended.shape[1], device=device)
    expected = ((t / (lengths.to(device)[:, None] - 1)).clamp(max=1) * 99).round().long()
    assert torch.equal(idx, expected)
    # the balance of the two springs on the position: K_h (x_h - x) + K (mu - x) = 0
    mu, k = guide.mean[idx], guide.stiffness[idx]
    residual = k_h * (intended[..., :3] - res.poses[..., :3]) + k[..., :3] * (
        mu[..., :3] - res.poses[..., :3]
    )
    assert float(residual.abs().max()) < 1e-9
    ones = torch.ones(intended.shape[:2], dtype=F64, device=device)
    torch.testing.assert_close(res.poses[..., 3:].norm(dim=-1), ones)
    # limits: a limp hand follows the mean exactly; no fixture (gain 0) leaves the person alone
    limp = guide.assist(
        intended, lengths=lengths, human_position_stiffness=0.0, human_rotation_stiffness=0.0
    )
    assert float(quaternion_distance(limp.poses[..., 3:], mu[..., 3:]).max()) < 1e-6
    torch.testing.assert_close(limp.poses[..., :3], mu[..., :3])
    off = HapticGuidance(model, position_gain=0.0, rotation_gain=0.0).assist(
        intended, lengths=lengths
    )
    torch.testing.assert_close(off.poses[..., :3], intended[..., :3])
    assert float(quaternion_distance(off.poses[..., 3:], intended[..., 3:]).max()) < 1e-6
    # q and -q in the intended poses: the same assisted poses (up to their sign)
    flipped = intended.clone()
    flipped[:, ::3, 3:] *= -1
    again = guide.assist(flipped, lengths=lengths)
    torch.testing.assert_close(again.poses[..., :3], res.poses[..., :3])
    assert float(quaternion_distance(again.poses[..., 3:], res.poses[..., 3:]).max()) < 1e-6


def test_assist_refuses_bad_lengths_and_shapes(promp, gen):
    guide = HapticGuidance(promp)
    intended, lengths = SimulatedOperator().intentions(BeamWindowTask(), 3, gen)
    with pytest.raises(ValueError, match="lengths must be"):
        guide.assist(intended, lengths=lengths + 10_000)
    with pytest.raises(ValueError, match=r"pose trajectory"):
        guide.assist(intended[..., :6])
    with pytest.raises(ValueError, match="human_position_stiffness must be finite and >= 0"):
        guide.assist(intended, human_position_stiffness=-1.0)
    with pytest.raises(ValueError, match=r"phase must lie in \[0, 1\]"):
        guide.stiffness_at(1.5)
    assert math.isfinite(float(guide.stiffness.max()))
