"""Damped-least-squares inverse kinematics of an :class:`~protorch.robots.ArmKinematics` chain's
end link (:meth:`~protorch.robots.ArmKinematics.inverse`), batched over targets."""

from __future__ import annotations

import torch
from torch import Tensor

from ..checks import check_tensor

__all__ = ["inverse_kinematics", "ik_seeds", "seed_label"]

SEED_SPREAD = 0.25  # a perturbed seed: the middle plus up to this fraction of each joint's range


def inverse_kinematics(
    kin,
    position: Tensor,
    q0: Tensor,
    *,
    rotation: Tensor | None = None,
    rest: Tensor | None = None,
    iters: int = 30,
    damping: float = 0.02,
    rotation_weight: float = 0.3,
    null_gain: float = 0.2,
    max_step: float = 0.3,
    tol: float = 1e-5,
    compiled: bool = False,
) -> tuple[Tensor, Tensor]:
    """Damped-least-squares inverse kinematics of the end link, batched:
    ``position (B, 3)`` (and optionally ``rotation (B, 3, 3)``) from ``q0 (B, J)``.

    Each iteration: ``dq = J^T (J J^T + damping^2 I)^-1 e`` with ``e`` the position error and
    ``rotation_weight`` times the orientation error ``0.5 sum_i r_i x r*_i``; plus, when
    ``rest (J,)`` or ``(B, J)`` is given, ``null_gain (rest - q)`` projected onto the
    Jacobian's null space (keeps the elbow near a posture); the step is scaled to at most
    ``max_step`` rad and the result clamped into the joint limits. Stops early once every
    position error (and orientation error, in rad) is below ``tol``. ``compiled``: the Jacobian
    and pose by :meth:`~protorch.robots.ArmKinematics.jacobian_pose` (several times faster, equal
    to round-off) instead of ``pytorch_kinematics``. Returns
    ``(q (B, J), position error (B,))``.
    """
    q = kin.check_joints(q0, "q0").clone()  # (B, J)
    if q.device != kin.lower.device:
        raise ValueError(
            f"q0 is on {q.device} but the chain is on {kin.lower.device}: move one with .to()"
        )
    position = check_tensor(position, "position", ndim=2).to(q)  # (B, 3)
    if position.shape != (q.shape[0], 3):
        raise ValueError(f"position must be ({q.shape[0]}, 3), got {tuple(position.shape)}")
    if rotation is not None:
        rotation = check_tensor(rotation, "rotation", ndim=3).to(q)  # (B, 3, 3)
    eye6 = torch.eye(6 if rotation is not None else 3, dtype=q.dtype, device=q.device)
    eye_j = torch.eye(kin.num_joints, dtype=q.dtype, device=q.device)
    lo, hi = kin.lower.to(q), kin.upper.to(q)
    err = torch.full((q.shape[0],), float("inf"), dtype=q.dtype, device=q.device)
    for _ in range(int(iters)):
        # (B, 6, J), (B, 4, 4)
        jac, pose = kin.jacobian_pose(q) if compiled else kin.chain.jacobian(q, ret_eef_pose=True)
        e_p = position - pose[:, :3, 3]  # (B, 3)
        err = e_p.norm(dim=-1)  # (B,)
        done = err < tol  # (B,)
        if rotation is not None:
            e_o = 0.5 * torch.linalg.cross(pose[:, :3, :3], rotation, dim=1).sum(-1)  # (B, 3)
            done = done & (e_o.norm(dim=-1) < tol)
        if bool(done.all()):
            break
        if rotation is not None:
            e = torch.cat([e_p, rotation_weight * e_o], -1)  # (B, 6)
            jac = torch.cat([jac[:, :3], rotation_weight * jac[:, 3:]], 1)  # (B, 6, J)
        else:
            e, jac = e_p, jac[:, :3]  # (B, 3), (B, 3, J)
        jjt = jac @ jac.transpose(1, 2) + damping**2 * eye6  # (B, r, r)
        pinv = jac.transpose(1, 2) @ torch.linalg.inv(jjt)  # (B, J, r) damped pseudo-inverse
        dq = (pinv @ e[..., None])[..., 0]  # (B, J)
        if rest is not None:  # the exact projector (the damped one would leak into the task)
            exact = jac.transpose(1, 2) @ torch.linalg.inv(jac @ jac.transpose(1, 2) + 1e-9 * eye6)
            null = eye_j - exact @ jac  # (B, J, J)
            dq = dq + (null @ (null_gain * (rest.to(q) - q))[..., None])[..., 0]
        scale = (max_step / dq.abs().amax(-1, keepdim=True).clamp_min(1e-12)).clamp(
            max=1.0
        )  # (B, 1)
        q = torch.minimum(torch.maximum(q + scale * dq, lo), hi)
    return q, err


def ik_seeds(lower: Tensor, upper: Tensor, count: int = 9, seed: int = 0) -> Tensor:
    """Starting poses for inverse kinematics, tried in order: the joint limits' middle, then
    ``count - 1`` poses perturbed from it by up to :data:`SEED_SPREAD` of each joint's range
    (uniform, a generator seeded with ``seed``: the same poses every call), clamped into the
    limits. ``lower, upper (J,)`` -> ``(count, J)``. The middle is often singular (an arm with
    symmetric limits stands straight up there); a perturbed seed leaves the singularity."""
    if count < 1:
        raise ValueError(f"count={count} must be at least 1")
    mid = 0.5 * (lower + upper)  # (J,)
    gen = torch.Generator().manual_seed(int(seed))
    u = torch.rand(count - 1, lower.shape[-1], generator=gen, dtype=torch.float64)  # (K-1, J)
    shift = (2 * u - 1).to(lower) * SEED_SPREAD * (upper - lower)  # (K-1, J)
    return torch.cat([mid[None], torch.minimum(torch.maximum(mid + shift, lower), upper)])


def seed_label(k: int, seeds: Tensor) -> str:
    """How seed ``k`` of :func:`ik_seeds` is reported: the middle, or the perturbed pose."""
    if k == 0:
        return "the joint limits' middle"
    pose = ", ".join(f"{v:.3f}" for v in seeds[k].tolist())
    return f"perturbed seed {k} of {seeds.shape[0] - 1} ([{pose}] rad; the middle failed)"
