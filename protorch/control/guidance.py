"""Haptic guidance from a pose ProMP (the paper's Sec. IV-A): a virtual fixture that pulls the
device towards the distribution's mean, stiffer where the distribution is narrow.

The force at phase ``z`` on the device pose ``x`` (7-D: position and quaternion) is

    F(z) = K(z) (mu(z) - x),    K_d(z) = clip(gain / sigma_d(z), k_min, k_max)   (per coordinate d)

with ``mu`` and ``sigma`` the ProMP's mean and marginal std at the phase
(:meth:`PoseProMP.std_trajectory`).
Where the optimised ProMP is sure (small std: the window, the start and end), the fixture is stiff;
where many trajectories are good (large std), the operator moves freely. The clip keeps the
stiffness in what a haptic device renders stably (and finite where the std is 0). The position
part is a force (N with the gains in N and N/m); the quaternion part acts on the sign-aligned
quaternion components (a device renders it as a torque towards ``mu``'s orientation).

**Phase.** ``F(t) = K(t) (mu(t) - x)``: the guidance replays the ProMP over the duration of the
motion, ``z = t / duration`` (:meth:`HapticGuidance.phase_indices`), so a person who is early or
late along the path feels that too. (A phase projected from the device's position onto the mean
path is not offered: it is ill-defined where the mean turns the beam while its position barely
moves, at the start and the end.)

**A simulated assisted operator** (:meth:`HapticGuidance.assist`): the hand holds the device with
its own stiffness ``K_h`` around the pose the person intends; the device settles where the two
springs balance, ``K_h (x_h - x) + K (mu - x) = 0``, i.e.
``x = x_h + K / (K + K_h) (mu - x_h)`` per coordinate (a quasi-static model: the device's and
hand's dynamics are much faster than the motion). With ``K >> K_h`` the device follows the mean;
with ``K << K_h`` it follows the person.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ..checks import check_tensor
from ..primitives.pose import POSE_DIM, align_quaternions, normalize_poses

__all__ = ["HapticGuidance", "GuidedTrials", "stiffness_law", "guidance_force"]

STIFFNESS_DEFAULTS = dict(
    position_gain=30.0,
    position_max=3000.0,
    position_min=0.0,
    rotation_gain=0.3,
    rotation_max=30.0,
    rotation_min=0.0,
)  # the stiffness law's settings (HapticGuidance.check_settings, teleop_guide.GUIDE_DEFAULTS)


def _nonneg(value, name: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {value}")
    return v


def stiffness_law(std: Tensor, gain, k_max, k_min=0.0) -> Tensor:
    """``K = clip(gain / std, k_min, k_max)``, elementwise; ``std = 0`` gives ``k_max``.

    ``gain``, ``k_max``, ``k_min`` broadcast against ``std`` (one per coordinate, say)."""
    std = check_tensor(std, "std")
    if bool((std < 0).any()):
        raise ValueError("std must be >= 0")
    gain, k_max, k_min = (
        torch.as_tensor(v, dtype=std.dtype, device=std.device) for v in (gain, k_max, k_min)
    )
    for v, name in ((gain, "gain"), (k_max, "k_max"), (k_min, "k_min")):
        check_tensor(v, name)
        if bool((v < 0).any()):
            raise ValueError(f"{name} must be >= 0")
    if bool((k_min > k_max).any()):
        raise ValueError("k_min must be <= k_max")
    safe = torch.where(std > 0, std, torch.ones_like(std))
    k = torch.where(std > 0, gain / safe, torch.full_like(std, float("inf")))
    return torch.minimum(torch.maximum(k, k_min), k_max)


def guidance_force(stiffness: Tensor, target: Tensor, pose: Tensor) -> Tensor:
    """``F = K (mu - x)`` on 7-D poses ``(..., 7)`` (broadcast); the quaternion of ``pose`` is taken
    in the hemisphere of ``target``'s first, so ``x`` and ``-x`` feel the same force."""
    q_t, q_x = target[..., 3:], pose[..., 3:]
    q_x = torch.where((q_x * q_t).sum(-1, keepdim=True) < 0, -q_x, q_x)
    delta = torch.cat([target[..., :3] - pose[..., :3], q_t - q_x], -1)  # (..., 7)
    return stiffness * delta


@dataclass
class GuidedTrials:
    """Simulated assisted trials: device poses ``(B, T, 7)``, phase index per step ``(B, T)``,
    stiffness ``(B, T, 7)`` and guidance force ``(B, T, 7)`` felt at each step."""

    poses: Tensor
    phase_index: Tensor
    stiffness: Tensor
    force: Tensor


class HapticGuidance(nn.Module):
    """The virtual fixture of a :class:`~protorch.primitives.pose.PoseProMP` (see the module
    docstring).

    Args:
        promp: the (optimised) pose ProMP; its mean and std on the phase grid are copied.
        position_gain, position_max, position_min: ``gain`` (N), ``k_max``, ``k_min`` (N/m) of the
            three position coordinates.
        rotation_gain, rotation_max, rotation_min: the same for the four quaternion components.
    """

    def __init__(
        self,
        promp,
        *,
        position_gain: float = 30.0,
        position_max: float = 3000.0,
        position_min: float = 0.0,
        rotation_gain: float = 0.3,
        rotation_max: float = 30.0,
        rotation_min: float = 0.0,
    ) -> None:
        super().__init__()
        cfg = self.check_settings(
            position_gain=position_gain,
            position_max=position_max,
            position_min=position_min,
            rotation_gain=rotation_gain,
            rotation_max=rotation_max,
            rotation_min=rotation_min,
        )
        gains = [cfg["position_gain"], cfg["rotation_gain"]]
        maxes = [cfg["position_max"], cfg["rotation_max"]]
        mins = [cfg["position_min"], cfg["rotation_min"]]
        mean = promp.mean_trajectory().detach()  # (T, 7)
        std = promp.std_trajectory().detach()  # (T, 7)
        per = lambda a, b: torch.tensor([a] * 3 + [b] * 4, dtype=mean.dtype, device=mean.device)  # noqa: E731
        self.register_buffer("mean", mean)  # (T, 7)
        self.register_buffer("std", std)  # (T, 7)
        self.register_buffer("gain", per(*gains))  # (7,)
        self.register_buffer("k_max", per(*maxes))  # (7,)
        self.register_buffer("k_min", per(*mins))  # (7,)
        self.register_buffer(
            "stiffness", stiffness_law(std, self.gain, self.k_max, self.k_min)
        )  # (T, 7)

    @staticmethod
    def check_settings(**settings) -> dict:
        """Validate the keyword arguments of the constructor (without a ProMP); return them with
        the defaults filled in. Raises a ``ValueError`` naming the bad setting."""
        defaults = STIFFNESS_DEFAULTS
        unknown = sorted(set(settings) - set(defaults))
        if unknown:
            raise ValueError(f"unknown guidance setting(s) {unknown}; allowed: {sorted(defaults)}")
        cfg = {**defaults, **settings}
        for key in defaults:
            cfg[key] = _nonneg(cfg[key], key)
        for n in ("position", "rotation"):
            if cfg[f"{n}_min"] > cfg[f"{n}_max"]:
                raise ValueError(
                    f"{n}_min ({cfg[f'{n}_min']}) must be <= {n}_max ({cfg[f'{n}_max']})"
                )
        return cfg

    @property
    def num_steps(self) -> int:
        return self.mean.shape[0]

    def index_of(self, phase) -> Tensor:
        """Phase(s) in ``[0, 1]`` -> nearest grid index (long)."""
        phase = torch.as_tensor(phase, dtype=self.mean.dtype, device=self.mean.device)
        if bool(((phase < 0) | (phase > 1)).any()) or not bool(torch.isfinite(phase).all()):
            raise ValueError("phase must lie in [0, 1]")
        return (phase * (self.num_steps - 1)).round().long()

    def stiffness_at(self, phase) -> Tensor:
        """``K(z)``: ``(..., 7)`` for phases ``(...)``."""
        return self.stiffness[self.index_of(phase)]

    def force(self, phase, pose: Tensor) -> Tensor:
        """``F(z) = K(z) (mu(z) - x)`` for phases ``(...)`` and poses ``(..., 7)``: ``(..., 7)``."""
        pose = check_tensor(pose, "pose").to(self.mean)
        if pose.shape[-1] != POSE_DIM:
            raise ValueError(f"pose must be (..., 7), got shape {tuple(pose.shape)}")
        i = self.index_of(phase)
        return guidance_force(self.stiffness[i], self.mean[i], pose)

    def phase_indices(self, intended: Tensor, *, lengths: Tensor | None = None) -> Tensor:
        """Grid index of the phase at every step of trials ``intended (B, T, ...)``: ``(B, T)``
        long.

        The phase runs with the clock over each trial's duration, ``z_t = t / (L - 1)`` (``lengths
        (B,)``, default ``T``; steps after a trial's end stay at ``z = 1``)."""
        b, steps = intended.shape[:2]
        dev = intended.device
        if lengths is None:
            lengths = torch.full((b,), steps, device=dev)
        lengths = torch.as_tensor(lengths, device=dev).reshape(-1)
        if lengths.shape != (b,) or bool((lengths < 2).any()) or bool((lengths > steps).any()):
            raise ValueError(
                f"lengths must be ({b},) integers in [2, {steps}], got {lengths.tolist()}"
            )
        t = torch.arange(steps, device=dev, dtype=self.mean.dtype)  # (T,)
        z = (t / (lengths[:, None].to(self.mean.dtype) - 1)).clamp(max=1)  # (B, T)
        return (z * (self.num_steps - 1)).round().long()

    def assist(
        self,
        intended: Tensor,
        *,
        lengths: Tensor | None = None,
        human_position_stiffness: float = 300.0,
        human_rotation_stiffness: float = 3.0,
    ) -> GuidedTrials:
        """Simulate the guided device for operators who intend the poses ``intended (B, T, 7)``
        (trial ``i`` lasting ``lengths[i]`` steps; the rest repeats its last pose).

        At each step the device settles where the hand's spring (stiffness ``K_h``) and the
        fixture balance: ``x = x_h + K / (K + K_h) (mu - x_h)`` per coordinate, its quaternion
        renormalised (see the module docstring), at the phase of :meth:`phase_indices`.
        """
        x_h = normalize_poses(intended, "intended").to(self.mean)  # (B, T, 7)
        if x_h.ndim != 3:
            raise ValueError(f"intended must be (B, T, 7), got shape {tuple(x_h.shape)}")
        k_pos = _nonneg(human_position_stiffness, "human_position_stiffness")
        k_rot = _nonneg(human_rotation_stiffness, "human_rotation_stiffness")
        k_h = torch.tensor([k_pos] * 3 + [k_rot] * 4, dtype=x_h.dtype, device=x_h.device)  # (7,)
        idx = self.phase_indices(x_h, lengths=lengths)  # (B, T)
        k, mu = self.stiffness[idx], self.mean[idx]  # (B, T, 7)
        q_h = x_h[..., 3:]
        q_h = torch.where(
            (q_h * mu[..., 3:]).sum(-1, keepdim=True) < 0, -q_h, q_h
        )  # mu's hemisphere
        hand = torch.cat([x_h[..., :3], q_h], -1)  # (B, T, 7)
        total = k + k_h
        share = torch.where(
            total > 0,
            k / torch.where(total > 0, total, torch.ones_like(total)),
            torch.zeros_like(total),
        )  # (B, T, 7); K = K_h = 0: the hand alone
        x = hand + share * (mu - hand)  # (B, T, 7)
        q = x[..., 3:] / torch.linalg.vector_norm(x[..., 3:], dim=-1, keepdim=True).clamp_min(1e-12)
        x = torch.cat([x[..., :3], align_quaternions(q)], -1)
        return GuidedTrials(poses=x, phase_index=idx, stiffness=k, force=guidance_force(k, mu, x))
