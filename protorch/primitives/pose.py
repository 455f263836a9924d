"""Poses as 7-D vectors and ProMPs over pose trajectories.

A pose is ``(x, y, z, qw, qx, qy, qz)``: a position and a unit quaternion, real part first (the
convention of ``pytorch_kinematics.transforms``, whose conversions are used here). ``q`` and
``-q`` are the same rotation, so every function below either is invariant to the sign of each
quaternion or makes the signs consistent first:

* **compared**: :func:`quaternion_distance` is the geodesic angle ``2 acos |<q1, q2>|``, the
  same for ``q`` and ``-q``;
* **fitted**: :meth:`PoseProMP.fit` renormalises every demonstrated quaternion, makes each
  demonstration sign-continuous along time and puts all of them in the hemisphere of one
  reference, so that averaging weights averages rotations, not a rotation and its antipode;
* **sampled / generated**: :meth:`PoseProMP.trajectory` renormalises the quaternion part of
  ``Phi w`` (the ProMP mean of unit quaternions is not unit) and makes it sign-continuous;
* **resampled**: :func:`resample_poses` interpolates neighbouring quaternions in the same
  hemisphere (normalised linear interpolation, equal to slerp to second order in the step).

Tensors carry shape comments: ``T`` time steps, ``n`` demonstrations, ``S`` samples.
"""

from __future__ import annotations

import copy
from typing import Sequence

import torch
from torch import Tensor, nn

from ..checks import check_tensor
from .promp import ProMP, demo_list
from .quaternions import quaternion_to_matrix

__all__ = [
    "POSE_DIM",
    "PoseProMP",
    "check_unit_quaternion",
    "normalize_quaternion",
    "align_quaternions",
    "quaternion_distance",
    "quaternion_path_length",
    "quaternion_slerp",
    "normalize_poses",
    "resample_poses",
    "rotation_matrix",
]

POSE_DIM = 7  # x, y, z, qw, qx, qy, qz
_MIN_NORM = 1e-8  # a quaternion shorter than this has no direction: refused, never divided by


def _norm(x: Tensor) -> Tensor:
    """Euclidean norm over the last axis, kept: ``(..., D) -> (..., 1)``."""
    return torch.linalg.vector_norm(x, dim=-1, keepdim=True)


# ----------------------------------------------------------------------------- quaternions
def _check_last(x: Tensor, size: int, name: str, what: str) -> None:
    if x.ndim < 1 or x.shape[-1] != size:
        raise ValueError(
            f"{name} must be {what} with last dimension {size}, got shape {tuple(x.shape)}"
        )


def normalize_quaternion(q, name: str = "q") -> Tensor:
    """``q (..., 4)`` divided by its norm; refuses NaN / inf and (near-)zero quaternions."""
    q = check_tensor(q, name)
    if not q.is_floating_point():
        q = q.to(torch.get_default_dtype())
    _check_last(q, 4, name, "quaternions (..., 4) (w, x, y, z)")
    norm = _norm(q)  # (..., 1)
    if q.numel() and bool((norm < _MIN_NORM).any()):
        raise ValueError(
            f"{name} contains a zero quaternion (norm < {_MIN_NORM:g}): it is no rotation"
        )
    return q / norm


def check_unit_quaternion(q, name: str = "q", *, tol: float = 1e-6) -> Tensor:
    """Return ``q (..., 4)`` renormalised after checking it is finite and unit to within ``tol``.

    For quaternions a user writes down (task poses): a norm far from 1 is a typo, not rounding."""
    q = check_tensor(q, name)
    if not q.is_floating_point():
        q = q.to(torch.get_default_dtype())
    _check_last(q, 4, name, "a quaternion (w, x, y, z)")
    norm = q.norm(dim=-1)  # (...)
    bad = (norm - 1).abs() > tol
    if bool(bad.any()):
        raise ValueError(
            f"{name} must be a unit quaternion (w, x, y, z): its norm is "
            f"{float(norm[bad].reshape(-1)[0]):.6g}, "
            f"not 1 (tolerance {tol:g})"
        )
    return q / norm[..., None]


def align_quaternions(q: Tensor, reference: Tensor | None = None) -> Tensor:
    """Make a quaternion trajectory ``q (..., T, 4)`` sign-continuous along ``T``.

    Each ``q_t`` is flipped when needed so that ``<q_t, q_{t-1}> >= 0`` (the shorter way between
    neighbours). With ``reference (..., 4)`` (or ``(4,)``), the whole trajectory is then flipped so
    that ``<q_0, reference> >= 0``. No renormalisation; the rotations are unchanged.
    """
    if q.ndim < 2 or q.shape[-1] != 4:
        raise ValueError(
            f"q must be a quaternion trajectory (..., T, 4), got shape {tuple(q.shape)}"
        )
    dots = (q[..., 1:, :] * q[..., :-1, :]).sum(-1)  # (..., T-1)
    step = torch.where(dots < 0, -torch.ones_like(dots), torch.ones_like(dots))  # (..., T-1)
    sign = torch.cat([torch.ones_like(q[..., :1, 0]), step], -1).cumprod(-1)  # (..., T)
    out = q * sign[..., None]  # (..., T, 4)
    if reference is not None:
        ref = torch.as_tensor(reference, dtype=q.dtype, device=q.device)
        first = (out[..., 0, :] * ref).sum(-1)  # (...)
        out = torch.where((first < 0)[..., None, None], -out, out)
    return out


def quaternion_distance(q1: Tensor, q2: Tensor) -> Tensor:
    """Geodesic angle in ``[0, pi]`` between the rotations of ``q1 (..., 4)`` and ``q2 (..., 4)``
    (broadcast). The same for ``q`` and ``-q``; inputs are renormalised.

    Computed as ``4 atan2(|q1 - s q2|, |q1 + s q2|)``, ``s = sign <q1, q2>``: exact near 0, where
    ``2 acos |<q1, q2>|`` loses half its digits."""
    q1 = q1 / _norm(q1).clamp_min(_MIN_NORM)
    q2 = q2 / _norm(q2).clamp_min(_MIN_NORM)
    s = torch.where((q1 * q2).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(q1.dtype)  # (..., 1)
    return 4 * torch.atan2(_norm(q1 - s * q2)[..., 0], _norm(q1 + s * q2)[..., 0])


def quaternion_path_length(q: Tensor) -> Tensor:
    """Total rotation angle of a trajectory of quaternions ``q (..., T, 4)``: the sum of the
    neighbours' angles (:func:`quaternion_distance`), ``(...)``. Sign-invariant."""
    return quaternion_distance(q[..., 1:, :], q[..., :-1, :]).sum(-1)


def quaternion_slerp(q0: Tensor, q1: Tensor, t: Tensor | float) -> Tensor:
    """Spherical interpolation from ``q0`` to ``q1`` (``(..., 4)``, broadcast) at ``t`` (``(...)``
    or a float) along the shorter arc (``q1`` is taken in ``q0``'s hemisphere); unit output.
    Falls back to normalised linear interpolation below 1e-6 rad, where both agree."""
    q0 = q0 / _norm(q0).clamp_min(_MIN_NORM)
    q1 = q1 / _norm(q1).clamp_min(_MIN_NORM)
    t = torch.as_tensor(t, dtype=q0.dtype, device=q0.device)[..., None]  # (..., 1)
    dot = (q0 * q1).sum(-1, keepdim=True)  # (..., 1)
    q1 = torch.where(dot < 0, -q1, q1)
    theta = 0.5 * quaternion_distance(q0, q1)[..., None]  # (..., 1) half the rotation angle
    small = theta < 1e-6
    sin_t = torch.where(small, torch.ones_like(theta), theta.sin())
    w0 = torch.where(small, 1 - t, ((1 - t) * theta).sin() / sin_t)
    w1 = torch.where(small, t, (t * theta).sin() / sin_t)
    out = w0 * q0 + w1 * q1
    return out / _norm(out).clamp_min(_MIN_NORM)


def rotation_matrix(q: Tensor) -> Tensor:
    """``q (..., 4)`` -> ``(..., 3, 3)`` (pytorch_kinematics' conversion; ``q`` and
    ``-q`` agree)."""
    return quaternion_to_matrix(q)


# ----------------------------------------------------------------------------- pose trajectories
def normalize_poses(traj, name: str = "trajectory") -> Tensor:
    """A pose trajectory ``(..., T, 7)`` with unit, sign-continuous quaternions.

    Refuses a wrong shape, NaN / inf and zero quaternions with an error naming ``name``."""
    traj = check_tensor(traj, name)
    if not traj.is_floating_point():
        traj = traj.to(torch.get_default_dtype())
    if traj.ndim < 2 or traj.shape[-1] != POSE_DIM:
        raise ValueError(
            f"{name} must be a pose trajectory (..., T, 7) = position (3) + quaternion (w, x, y, "
            "z), "
            f"got shape {tuple(traj.shape)}"
        )
    q = align_quaternions(normalize_quaternion(traj[..., 3:], f"{name} quaternions"))  # (..., T, 4)
    return torch.cat([traj[..., :3], q], -1)


def resample_poses(traj: Tensor, num_steps: int) -> Tensor:
    """Resample a pose trajectory ``(..., T, 7)`` to ``(..., num_steps, 7)`` on a uniform phase.

    Positions are interpolated linearly, quaternions linearly between sign-aligned neighbours and
    renormalised (nlerp: slerp to second order in the step, so for a dense grid the same path)."""
    if int(num_steps) < 2:
        raise ValueError(f"num_steps must be >= 2, got {num_steps}")
    return _resample_normalized(normalize_poses(traj), int(num_steps))


def _resample_normalized(traj: Tensor, num_steps: int) -> Tensor:
    """:func:`resample_poses` of an already normalised, sign-continuous trajectory."""
    t_in = traj.shape[-2]
    if t_in == num_steps:
        return traj
    pos = torch.linspace(0, t_in - 1, int(num_steps), dtype=traj.dtype, device=traj.device)  # (M,)
    lo = pos.floor().long().clamp(0, t_in - 1)
    hi = (lo + 1).clamp(max=t_in - 1)
    frac = (pos - lo.to(traj.dtype))[:, None]  # (M, 1)
    out = traj[..., lo, :] * (1 - frac) + traj[..., hi, :] * frac  # (..., M, 7)
    q = out[..., 3:]
    q = q / _norm(q).clamp_min(_MIN_NORM)
    return torch.cat([out[..., :3], q], -1)


# ----------------------------------------------------------------------------- pose ProMP
class PoseProMP(nn.Module):
    """A ProMP over pose trajectories: a 3-DoF position ProMP and a 4-DoF quaternion ProMP.

    The two share basis, phase and step count and are kept as two modules (``position``,
    ``orientation``) because the paper optimises position and orientation as two separate PRO
    problems: each has its own weight vector (``3 K`` and ``4 K`` weights) and diagonal Gaussian.

    Args:
        num_basis, num_steps, width, ridge, dtype, device: as
        :class:`~protorch.primitives.promp.ProMP`.
    """

    def __init__(
        self,
        num_basis: int = 10,
        num_steps: int = 100,
        *,
        width: float | None = None,
        ridge: float = 1e-11,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        self.position = ProMP(
            3, num_basis, num_steps, width=width, ridge=ridge, dtype=dtype, device=device
        )
        self.orientation = ProMP(
            4, num_basis, num_steps, width=width, ridge=ridge, dtype=dtype, device=device
        )

    @property
    def num_steps(self) -> int:
        return self.position.num_steps

    @property
    def phase(self) -> Tensor:
        """``(T,)`` in ``[0, 1]``."""
        return self.position.phase

    def extra_repr(self) -> str:
        return f"num_basis={self.position.num_basis}, num_steps={self.num_steps}"

    # ------------------------------------------------------------------ fitting
    def aligned_demos(self, demos: Tensor | Sequence[Tensor], reference=None) -> list[Tensor]:
        """Demonstrations ``(T_i, 7)`` with unit quaternions, sign-continuous in time and the first
        one in the hemisphere of ``reference (4,)`` (default: the first demonstration's first
        quaternion). This is what :meth:`fit` fits."""
        demos = demo_list(demos, "(n, T, 7) or a list of (T_i, 7), got shape")
        out = [
            normalize_poses(torch.as_tensor(d).to(self.position.basis), f"demos[{i}]")
            for i, d in enumerate(demos)
        ]
        if reference is None:
            ref = out[0][0, 3:]
        else:
            ref = normalize_quaternion(
                torch.as_tensor(reference).to(self.position.basis), "reference"
            )
        return [torch.cat([d[:, :3], align_quaternions(d[:, 3:], ref)], -1) for d in out]

    def fit(
        self, demos: Tensor | Sequence[Tensor], *, reference=None, min_var: float = 0.0
    ) -> "PoseProMP":
        """Fit both ProMPs (diagonal maximum likelihood) to demonstrations ``(T_i, 7)`` of any
        lengths, after :meth:`aligned_demos`."""
        aligned = self.aligned_demos(demos, reference)
        self.position.fit([d[:, :3] for d in aligned], min_var=min_var)
        self.orientation.fit([d[:, 3:] for d in aligned], min_var=min_var)
        return self

    def set_distribution(
        self,
        *,
        position: tuple[Tensor, Tensor] | None = None,
        orientation: tuple[Tensor, Tensor] | None = None,
    ) -> "PoseProMP":
        """Replace the ``(mean, var)`` of the position and / or orientation weight Gaussian."""
        if position is not None:
            self.position.set_distribution(position[0], var=position[1])
        if orientation is not None:
            self.orientation.set_distribution(orientation[0], var=orientation[1])
        return self

    def copy(self) -> "PoseProMP":
        return copy.deepcopy(self)

    # ------------------------------------------------------------------ generating
    def quaternions(self, w_rot: Tensor) -> Tensor:
        """Orientation weights ``(..., 4K)`` -> unit, sign-continuous quaternions
        ``(..., T, 4)``."""
        q = self.orientation.trajectory(w_rot)  # (..., T, 4)
        q = q / _norm(q).clamp_min(_MIN_NORM)
        return align_quaternions(q)

    def trajectory(self, w_pos: Tensor, w_rot: Tensor) -> Tensor:
        """Weights ``(..., 3K)`` and ``(..., 4K)`` -> pose trajectories ``(..., T, 7)``."""
        pos = self.position.trajectory(w_pos)  # (..., T, 3)
        q = self.quaternions(w_rot)  # (..., T, 4)
        lead = torch.broadcast_shapes(pos.shape[:-1], q.shape[:-1])  # (..., T)
        return torch.cat([pos.expand(*lead, 3), q.expand(*lead, 4)], -1)

    def mean_trajectory(self) -> Tensor:
        """``(T, 7)``: the position mean and the renormalised quaternion mean."""
        return self.trajectory(self.position.mean, self.orientation.mean)

    def std_trajectory(self) -> Tensor:
        """``(T, 7)``: marginal std of the 3 positions and of the 4 raw quaternion components."""
        return torch.cat([self.position.std_trajectory(), self.orientation.std_trajectory()], -1)

    def sample(
        self, num_samples: int, *, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor]:
        """Independent draws of both weight Gaussians: ``(S, 3K)``, ``(S, 4K)``."""
        return (
            self.position.sample(num_samples, generator=generator),
            self.orientation.sample(num_samples, generator=generator),
        )
