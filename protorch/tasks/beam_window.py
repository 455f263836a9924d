"""The assisted-teleoperation task of the paper's Sec. IV-A: a beam carried through a window.

A wall with a rectangular window stands at a given pose (position and orientation, so it may be
rotated). A beam (a segment of ``beam_length`` with a radius) must go from a start pose, through
the window, to an end pose. It is longer than the window is wide, so it must be turned upright to
pass, and turned back after. Poses are 7-D: position and a unit quaternion ``(w, x, y, z)``; the
beam lies along its body ``x`` axis (:data:`BEAM_AXIS`). Units: metres and radians.

Wall frame: the wall's quaternion maps the world axes to its local axes, whose columns are the
wall normal (local ``x``), the window's width direction (local ``y``) and its height direction
(local ``z``). The wall is a slab of ``wall_thickness`` around the plane ``x_local = 0``,
unbounded in ``y`` and ``z`` (no way around it), minus the window prism
``|y_local| < window_width / 2, |z_local| < window_height / 2``.

**Collision** (:meth:`BeamWindowTask.collides`). The beam at one instant is the segment between
its end points ``p +- (L / 2) u`` (``u`` its axis). The wall is inflated by ``beam_radius``
(thicker slab, smaller window), so a segment test is a conservative test of the beam as a capsule
(and of a box of half-diagonal ``beam_radius``). A segment collides when its part inside the slab
is not empty and not entirely inside the window prism; both sets are convex, so checking the two
end points of the clipped part is exact. A trajectory collides when the beam collides at any pose
of the trajectory resampled ``collision_substeps`` times more densely (positions linearly,
quaternions by nlerp).

**Objectives** (the paper: four via points, two at the window). Via points (:meth:`via_poses`):
the start pose, two poses on the window's axis ``via_offset`` before and after the wall, upright
(beam along the window's height, in the wall's orientation; :meth:`passing_quaternion`), and the
end pose. Position and orientation are two problems:

* position ``(..., T, 3) -> (..., 4)``: distance of ``tau(0)`` to the start, minimum over ``t`` of
  the distance to each window via point, distance of ``tau(T)`` to the end;
* orientation ``(..., T, 4) -> (..., 4)``: rotation angle to each via quaternion at the via
  point's phase (0, the phases where the position passes the window via points, 1);

each plus ``length_weight * length + jerk_weight * jerk``: path length (sum of steps; the total
rotation angle for orientations) and mean jerk (mean norm of the third finite difference per step
of a ``jerk_steps``-step grid over the motion; of the sign-aligned quaternion components for
orientations). PRO's reward is ``exp(-beta * cost)`` (shifted by the minimum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..checks import check_tensor
from ..primitives.pose import (
    align_quaternions,
    check_unit_quaternion,
    normalize_poses,
    normalize_quaternion,
    quaternion_distance,
    quaternion_path_length,
    resample_poses,
    rotation_matrix,
)
from ..primitives.quaternions import axis_angle_to_quaternion, quaternion_raw_multiply
from .base import Task
from .beam_operator import SimulatedOperator

__all__ = [
    "BeamWindowTask",
    "SimulatedOperator",
    "BEAM_AXIS",
    "quaternion_about",
    "as_vector",
    "as_positive",
]

BEAM_AXIS = (1.0, 0.0, 0.0)  # the beam lies along its body x axis
_VIA_NAMES = ("start", "window_front", "window_back", "end")


def quaternion_about(axis, angle: float, *, dtype=torch.float64, device=None) -> Tensor:
    """The unit quaternion ``(4,)`` of a rotation by ``angle`` (radians) about ``axis (3,)``."""
    a = torch.as_tensor(axis, dtype=dtype, device=device)
    a = a / a.norm()
    return axis_angle_to_quaternion(a * float(angle))


def as_vector(values, name: str, size: int) -> tuple[float, ...]:
    """``values`` as ``size`` finite floats; a ``ValueError`` naming ``name`` otherwise."""
    t = check_tensor(torch.as_tensor(values, dtype=torch.float64), name)
    if t.shape != (size,):
        raise ValueError(f"{name} must have {size} numbers, got shape {tuple(t.shape)}")
    return tuple(float(v) for v in t)


def as_positive(value, name: str) -> float:
    """``value`` as a finite float > 0; a ``ValueError`` naming ``name`` otherwise."""
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value}")
    return v


def _norm(x: Tensor) -> Tensor:
    """Euclidean norm over the last axis: ``(..., D) -> (...)``."""
    return torch.linalg.vector_norm(x, dim=-1)


def _jerk(x: Tensor, steps: int | None = None) -> Tensor:
    """Mean norm of the third finite difference along ``T``: ``x (..., T, D) -> (...)``.

    With ``steps``, the differences are rescaled to a grid of ``steps`` steps over the same
    phase, ``Delta^3 x * ((T - 1) / (steps - 1))^3`` (so the jerk does not depend on how finely
    the trajectory is evaluated); ``None``: per step of ``x``'s own grid."""
    t = x.shape[-2]
    if t < 4:
        return x.new_zeros(x.shape[:-2])
    d3 = x[..., 3:, :] - 3 * x[..., 2:-1, :] + 3 * x[..., 1:-2, :] - x[..., :-3, :]  # (..., T-3, D)
    scale = 1.0 if steps is None else ((t - 1) / (steps - 1)) ** 3
    return _norm(d3).mean(-1) * scale


def _closest_index(x: Tensor, points: Tensor) -> Tensor:
    """Index along ``T`` of the closest approach of ``x (..., T, 3)`` to each of
    ``points (P, 3)``."""
    return torch.stack([_norm(x - p).argmin(-1) for p in points], -1)


@dataclass
class BeamWindowTask(Task):
    """A beam through a window in a wall (see the module docstring for the model).

    Args:
        wall_position: ``(3,)`` centre of the window.
        wall_quaternion: ``(4,)`` orientation of the wall, unit ``(w, x, y, z)``: local ``x`` is
            the wall normal, local ``y`` the window's width, local ``z`` its height.
        window_width, window_height: the window's opening (metres).
        wall_thickness: thickness of the wall slab.
        beam_length: ``L``, longer than the window is wide; ``beam_radius``: the beam's radius
            (the wall is inflated by it).
        start_position, start_quaternion, end_position, end_quaternion: the task's poses, on the
            two sides of the wall.
        via_offset: distance of the two window via points before / after the window centre,
            along the wall normal.
        length_weight, jerk_weight: the paper's 0.1 and 1e5.
        jerk_steps: the jerk is the third difference per step of a trajectory of ``jerk_steps``
            steps over the motion (rescaled from the grid it is evaluated on); ``None``: per step
            of the evaluated trajectory. The default, 1000, is a 1 s motion sampled at a haptic
            device's 1 kHz.
        collision_substeps: dense resampling factor of a trajectory for the collision check.
        position_tol, angle_tol: success tolerances on the start and end poses (m, rad).
    """

    wall_position: tuple = (0.6, 0.0, 0.5)
    wall_quaternion: tuple = (0.984807753, 0.0, 0.0, 0.173648178)  # 20 deg about z
    window_width: float = 0.2
    window_height: float = 0.8
    wall_thickness: float = 0.05
    beam_length: float = 0.6
    beam_radius: float = 0.015
    start_position: tuple = (0.0, 0.0, 0.45)
    start_quaternion: tuple = (0.707106781, 0.0, 0.0, 0.707106781)  # beam along world y
    end_position: tuple = (1.2, 0.15, 0.5)
    end_quaternion: tuple = (0.573576436, 0.0, 0.0, 0.819152044)  # beam horizontal, yaw 110 deg
    via_offset: float = 0.15
    length_weight: float = 0.1
    jerk_weight: float = 1e5
    jerk_steps: int | None = 1000
    collision_substeps: int = 2
    position_tol: float = 0.05
    angle_tol: float = math.radians(10.0)
    name: str = "beam_window"
    objective_names: tuple[str, ...] = field(default=_VIA_NAMES, init=False)

    def __post_init__(self) -> None:
        self.wall_position = as_vector(self.wall_position, "wall_position", 3)
        self.start_position = as_vector(self.start_position, "start_position", 3)
        self.end_position = as_vector(self.end_position, "end_position", 3)
        for key in ("wall_quaternion", "start_quaternion", "end_quaternion"):
            q = check_unit_quaternion(
                torch.as_tensor(getattr(self, key), dtype=torch.float64), key, tol=1e-3
            )
            if q.shape != (4,):
                raise ValueError(
                    f"{key} must be one quaternion (w, x, y, z), got shape {tuple(q.shape)}"
                )
            setattr(self, key, tuple(float(v) for v in q))
        for key in (
            "window_width",
            "window_height",
            "wall_thickness",
            "beam_length",
            "via_offset",
            "position_tol",
            "angle_tol",
        ):
            setattr(self, key, as_positive(getattr(self, key), key))
        for key in ("beam_radius", "length_weight", "jerk_weight"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{key} must be finite and >= 0, got {getattr(self, key)}")
            setattr(self, key, v)
        if (
            isinstance(self.collision_substeps, bool)
            or int(self.collision_substeps) != self.collision_substeps
            or int(self.collision_substeps) < 1
        ):
            raise ValueError(
                f"collision_substeps must be an int >= 1, got {self.collision_substeps}"
            )
        self.collision_substeps = int(self.collision_substeps)
        if self.jerk_steps is not None:
            js = self.jerk_steps
            if isinstance(js, bool) or int(js) != js or int(js) < 4:
                raise ValueError(f"jerk_steps must be an int >= 4 or None, got {self.jerk_steps}")
            self.jerk_steps = int(self.jerk_steps)
        r = self.beam_radius
        if self.window_width <= 2 * r or self.window_height <= 2 * r:
            raise ValueError(
                f"the window ({self.window_width} x {self.window_height}) must be larger than the "
                "beam's "
                f"diameter ({2 * r})"
            )
        if self.beam_length <= self.window_width:
            raise ValueError(
                f"beam_length ({self.beam_length}) must exceed window_width ({self.window_width}): "
                "the task is "
                "a beam that has to be turned to pass"
            )
        side_start, side_end = self._side(self.start_position), self._side(self.end_position)
        if side_start * side_end >= 0:
            raise ValueError(
                "start_position and end_position must lie on opposite sides of the wall"
            )
        centre = torch.cat(
            [self._t(self.wall_position), self.passing_quaternion()]
        )  # upright in the window
        poses = torch.stack([*self.via_poses(), centre])  # (5, 7)
        hit = self.collides_at(poses)  # (5,)
        if bool(hit.any()):
            which = [n for n, h in zip(_VIA_NAMES + ("window_centre",), hit.tolist()) if h]
            raise ValueError(
                f"the pose(s) {which} put the beam inside the wall: the task cannot be solved "
                "(check the "
                "window height against beam_length + 2 beam_radius, via_offset against the wall "
                "thickness, and "
                "the start / end poses)"
            )

    # ------------------------------------------------------------------ geometry
    def _t(self, values, ref: Tensor | None = None) -> Tensor:
        kw = dict(dtype=torch.float64) if ref is None else dict(dtype=ref.dtype, device=ref.device)
        return torch.tensor(values, **kw)

    def _side(self, point) -> float:
        c, rot = self._t(self.wall_position), self.wall_rotation()
        return float((self._t(point) - c) @ rot[:, 0])

    def wall_rotation(self, ref: Tensor | None = None) -> Tensor:
        """``(3, 3)``: columns are the wall normal, the window's width and height directions."""
        return rotation_matrix(self._t(self.wall_quaternion, ref))

    def approach_direction(self, ref: Tensor | None = None) -> Tensor:
        """``(3,)``: the wall normal pointing from the start's side to the end's side."""
        n = self.wall_rotation(ref)[:, 0]
        return -n if self._side(self.start_position) > 0 else n

    def passing_quaternion(self, ref: Tensor | None = None) -> Tensor:
        """``(4,)``: the beam upright in the window (its axis along the window's height), in the
        wall's
        orientation: ``q_wall * q_x(90 deg) * q_z(90 deg)`` (the beam axis ``x`` -> ``y`` -> ``z``
        in the wall frame)."""
        kw = dict(dtype=torch.float64) if ref is None else dict(dtype=ref.dtype, device=ref.device)
        local = quaternion_raw_multiply(
            quaternion_about((1, 0, 0), math.pi / 2, **kw),
            quaternion_about((0, 0, 1), math.pi / 2, **kw),
        )
        q = quaternion_raw_multiply(self._t(self.wall_quaternion, ref), local)
        return q / q.norm()

    def via_poses(self, ref: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """The four via poses ``(7,)``: start, before the window, after the window, end. The two at
        the window are computed from the wall's pose: its centre ``-+ via_offset`` along the
        approach
        direction, in :meth:`passing_quaternion`."""
        c = self._t(self.wall_position, ref)
        a = self.approach_direction(ref)
        q_pass = self.passing_quaternion(ref)
        start = torch.cat([self._t(self.start_position, ref), self._t(self.start_quaternion, ref)])
        end = torch.cat([self._t(self.end_position, ref), self._t(self.end_quaternion, ref)])
        front = torch.cat([c - self.via_offset * a, q_pass])
        back = torch.cat([c + self.via_offset * a, q_pass])
        return start, front, back, end

    def via_array(self, ref: Tensor | None = None) -> Tensor:
        """``(4, 7)``: :meth:`via_poses` stacked."""
        return torch.stack(list(self.via_poses(ref)))

    def beam_endpoints(self, poses: Tensor) -> tuple[Tensor, Tensor]:
        """End points of the beam ``(..., 3)`` each, for poses ``(..., 7)`` (any quaternion norm
        and sign; a zero quaternion is refused)."""
        q = poses[..., 3:]
        n2 = (q * q).sum(-1)  # (...)
        if bool((n2 < 1e-16).any()):
            raise ValueError(
                "the poses contain a zero quaternion (norm < 1e-08): it is no rotation"
            )
        w, x, y, z = q.unbind(-1)  # (...)
        s2 = (
            2 / n2
        )  # the first column of the rotation matrix of q / |q|: the body x axis (BEAM_AXIS)
        axis = torch.stack(
            [1 - s2 * (y * y + z * z), s2 * (x * y + w * z), s2 * (x * z - w * y)], -1
        )  # (..., 3)
        half = 0.5 * self.beam_length * axis
        return poses[..., :3] - half, poses[..., :3] + half

    # ------------------------------------------------------------------ collision
    def _check_traj(self, traj, name: str = "trajectory") -> Tensor:
        return normalize_poses(traj, name)

    def collides_at(self, poses: Tensor) -> Tensor:
        """Whether the beam at each pose ``(..., 7)`` intersects the (inflated) wall: ``(...)``
        bool.

        Exact for a segment against a slab minus a rectangular prism (see the module docstring)."""
        poses = check_tensor(poses, "poses")
        if poses.shape[-1] != 7:
            raise ValueError(
                "poses must be (..., 7) = position + quaternion (w, x, y, z), got "
                f"{tuple(poses.shape)}"
            )
        if not poses.is_floating_point():
            poses = poses.to(torch.get_default_dtype())
        a, b = self.beam_endpoints(poses)  # (..., 3) each
        c, rot = self._t(self.wall_position, poses), self.wall_rotation(poses)
        (ax, ay, az), (bx, by, bz) = (
            ((a - c) @ rot).unbind(-1),
            ((b - c) @ rot).unbind(-1),
        )  # wall frame
        h = 0.5 * self.wall_thickness + self.beam_radius
        half_w = 0.5 * self.window_width - self.beam_radius
        half_h = 0.5 * self.window_height - self.beam_radius
        dx = bx - ax  # (...)
        moving = dx != 0
        safe = torch.where(moving, dx, torch.ones_like(dx))
        t1, t2 = (-h - ax) / safe, (h - ax) / safe  # (...) where the segment crosses the two faces
        inside_static = ax.abs() < h  # a segment parallel to the wall
        t_in = torch.where(
            moving, torch.minimum(t1, t2).clamp_min(0), torch.where(inside_static, 0.0, 1.0).to(dx)
        )
        t_out = torch.where(
            moving, torch.maximum(t1, t2).clamp_max(1), torch.where(inside_static, 1.0, 0.0).to(dx)
        )
        in_slab = t_in < t_out  # (...)

        def in_window(
            t: Tensor,
        ) -> Tensor:  # the point at segment parameter t, inside the window prism
            return ((ay + t * (by - ay)).abs() < half_w) & ((az + t * (bz - az)).abs() < half_h)

        return in_slab & ~(in_window(t_in) & in_window(t_out))

    def dense(self, traj: Tensor, substeps: int | None = None) -> Tensor:
        """The trajectory ``(..., T, 7)`` resampled ``substeps`` times more densely."""
        traj = self._check_traj(traj)
        k = self.collision_substeps if substeps is None else int(substeps)
        if k < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        t = traj.shape[-2]
        return traj if k == 1 or t < 2 else resample_poses(traj, (t - 1) * k + 1)

    def collides(self, traj: Tensor, substeps: int | None = None) -> Tensor:
        """Whether the beam hits the wall anywhere along ``traj (..., T, 7)``: ``(...)`` bool."""
        return self.collides_at(self.dense(traj, substeps)).any(-1)

    # ------------------------------------------------------------------ objectives
    def window_phases(self, positions: Tensor) -> Tensor:
        """Phases ``(..., 4)`` of the four via points along ``positions (..., T, 3)``: 0, the phases
        of the closest approach to the two window via points, 1."""
        if positions.ndim < 2 or positions.shape[-1] != 3:
            raise ValueError(f"positions must be (..., T, 3), got shape {tuple(positions.shape)}")
        via = self.via_array(positions)[:, :3]  # (4, 3)
        t = positions.shape[-2]
        idx = _closest_index(positions, via[1:3])  # (..., 2)
        z = idx.to(positions.dtype) / (t - 1)  # (..., 2)
        zeros = torch.zeros_like(z[..., :1])
        return torch.cat([zeros, z, zeros + 1], -1)  # (..., 4)

    def position_costs(self, positions: Tensor) -> Tensor:
        """``(..., T, 3) -> (..., 4)``: via-point distances + length and jerk terms."""
        positions = check_tensor(positions, "positions")
        if positions.ndim < 2 or positions.shape[-1] != 3 or positions.shape[-2] < 2:
            raise ValueError(
                f"positions must be (..., T, 3) with T >= 2, got shape {tuple(positions.shape)}"
            )
        via = self.via_array(positions)[:, :3]  # (4, 3)
        d_start = _norm(positions[..., 0, :] - via[0])  # (...)
        d_front = _norm(positions - via[1]).amin(-1)  # (...)
        d_back = _norm(positions - via[2]).amin(-1)  # (...)
        d_end = _norm(positions[..., -1, :] - via[3])  # (...)
        obj = torch.stack([d_start, d_front, d_back, d_end], -1)  # (..., 4)
        length = _norm(positions[..., 1:, :] - positions[..., :-1, :]).sum(-1)  # (...)
        extra = self.length_weight * length + self.jerk_weight * _jerk(
            positions, self.jerk_steps
        )  # (...)
        return obj + extra[..., None]

    def orientation_costs(self, quaternions: Tensor, phases: Tensor) -> Tensor:
        """``(..., T, 4)`` and via phases ``(4,)`` (or ``(..., 4)``) ``-> (..., 4)``: rotation angle
        to each via quaternion at its phase (nearest step) + length and jerk terms. Quaternions are
        renormalised and sign-aligned first, so ``q`` and ``-q`` (at any step) cost the same."""
        q = normalize_quaternion(quaternions, "quaternions")
        if q.ndim < 2 or q.shape[-2] < 2:
            raise ValueError(
                f"quaternions must be (..., T, 4) with T >= 2, got shape {tuple(q.shape)}"
            )
        phases = check_tensor(torch.as_tensor(phases, dtype=q.dtype, device=q.device), "phases")
        if phases.shape[-1:] != (4,):
            raise ValueError(f"phases must be (4,) or (..., 4), got shape {tuple(phases.shape)}")
        if bool(((phases < 0) | (phases > 1)).any()):
            raise ValueError("phases must lie in [0, 1]")
        q = align_quaternions(q)  # sign-continuous: the jerk of q, not of a sign flip
        t = q.shape[-2]
        idx = (phases * (t - 1)).round().long()  # (4,) or (..., 4)
        if idx.ndim == 1:
            at = q[..., idx, :]  # (..., 4, 4)
        else:
            idx = idx.expand(*q.shape[:-2], 4)
            at = q.gather(-2, idx[..., None].expand(*idx.shape, 4))  # (..., 4, 4)
        obj = quaternion_distance(at, self.via_array(q)[:, 3:])  # (..., 4)
        extra = self.length_weight * quaternion_path_length(q) + self.jerk_weight * _jerk(
            q, self.jerk_steps
        )
        return obj + extra[..., None]

    def costs(self, traj: Tensor) -> Tensor:
        """``(..., T, 7) -> (..., 8)``: the position objectives, then the orientation objectives at
        the phases where each trajectory's own position passes the window via points."""
        traj = self._check_traj(traj)
        pos, q = traj[..., :3], traj[..., 3:]
        return torch.cat(
            [self.position_costs(pos), self.orientation_costs(q, self.window_phases(pos))], -1
        )

    def via_errors(self, traj: Tensor) -> dict:
        """Distances (m) and angles (deg) of one trajectory ``(T, 7)`` to the four via poses."""
        traj = self._check_traj(traj)
        if traj.ndim != 2:
            raise ValueError(
                f"via_errors takes one trajectory (T, 7), got shape {tuple(traj.shape)}"
            )
        via = self.via_array(traj)
        z = self.window_phases(traj[:, :3])
        idx = (z * (traj.shape[0] - 1)).round().long()
        pos_err = (traj[idx, :3] - via[:, :3]).norm(dim=-1)
        ang_err = quaternion_distance(traj[idx, 3:], via[:, 3:])
        return {
            "phases": z.tolist(),
            "position_m": pos_err.tolist(),
            "angle_deg": torch.rad2deg(ang_err).tolist(),
        }

    def success(self, traj: Tensor) -> Tensor:
        """No collision along the densely resampled trajectory, and start and end poses within
        ``position_tol`` and ``angle_tol``: ``(...)`` bool."""
        traj = self._check_traj(traj)
        start, _, _, end = self.via_poses(traj)
        ok = torch.ones(traj.shape[:-2], dtype=torch.bool, device=traj.device)
        for pose, target in ((traj[..., 0, :], start), (traj[..., -1, :], end)):
            ok &= (pose[..., :3] - target[:3]).norm(dim=-1) <= self.position_tol
            ok &= quaternion_distance(pose[..., 3:], target[3:]) <= self.angle_tol
        return ok & ~self.collides(traj)
