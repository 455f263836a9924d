"""The beam through a window in a wall that moves: the environment of assisted teleoperation.

The geometry is the one of :class:`~protorch.tasks.BeamWindowTask` (the paper's Sec. IV-A): a wall
slab with a rectangular window, a beam (a segment of ``beam_length``, radius ``beam_radius``) going
from a start pose, through the window, to an end pose; poses are 7-D, position and unit quaternion
``(w, x, y, z)``, the beam along its body ``x`` axis. Metres, radians, seconds.

**The environment** is the wall's pose, ``env = (x, y, z, yaw)`` (``E = 4``): the window's centre
and the wall's rotation about the vertical (its normal is ``(cos yaw, sin yaw, 0)``). Every method
takes ``env (..., 4)`` broadcast against the poses, so one call checks many walls.

**Two classes.** The beam is longer than the window is wide, so it is turned upright to pass; it
can be rolled up either way about the wall normal: class 0 rolls it by +90 deg (its axis points
up in the window), class 1 by -90 deg (down). Both pass; a path of one class is never a path of
the other (they differ by a half turn about the normal), so the map keeps them apart
(:meth:`TeleopWindowTask.label`). The objectives take the closer class at the window.

**Objectives** ``costs(traj (..., T, 7), env (..., 4)) -> (..., 8)``: as the beam task's, the four
position via-point distances (start, ``via_offset`` before and after the window, end) and the four
rotation angles to the via orientations (the start's, the passing orientation of the closer class
at the two window phases, the end's), each plus ``length_weight * length + jerk_weight * jerk``.
**Success**: start and end within ``position_tol`` / ``angle_tol`` and no collision along the
trajectory resampled ``collision_substeps`` times more densely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..checks import check_tensor
from ..primitives.pose import (
    align_quaternions,
    normalize_poses,
    quaternion_distance,
    quaternion_path_length,
    resample_poses,
)
from ..primitives.quaternions import quaternion_raw_multiply
from .beam_window import as_positive, as_vector, quaternion_about

__all__ = ["TeleopWindowTask", "ENV_NAMES", "yaw_quaternion"]

ENV_NAMES = (
    "x",
    "y",
    "z",
    "yaw",
)  # the wall's pose: window centre (m), rotation about vertical (rad)


def _norm(x: Tensor) -> Tensor:
    return torch.linalg.vector_norm(x, dim=-1)


def _jerk(x: Tensor, steps: int) -> Tensor:
    """Mean norm of the third difference along ``T`` of ``x (..., T, D)``, per step of a
    ``steps``-step
    grid over the same phase (the beam task's jerk term): ``(...)``."""
    t = x.shape[-2]
    d3 = x[..., 3:, :] - 3 * x[..., 2:-1, :] + 3 * x[..., 1:-2, :] - x[..., :-3, :]  # (..., T-3, D)
    return _norm(d3).mean(-1) * ((t - 1) / (steps - 1)) ** 3


def yaw_quaternion(yaw: Tensor) -> Tensor:
    """``(...)`` angles about the vertical -> unit quaternions ``(..., 4)``."""
    h = 0.5 * yaw
    z = torch.zeros_like(h)
    return torch.stack([torch.cos(h), z, z, torch.sin(h)], -1)


@dataclass
class TeleopWindowTask:
    """A beam through the window of a wall whose pose is the environment (module docstring).

    Args:
        env_low, env_high: ``(4,)`` range of the wall poses the map is trained on
            (:meth:`sample_envs`), ``(x, y, z, yaw)``; a moving wall stays inside it.
        window_width, window_height, wall_thickness, beam_length, beam_radius: the geometry (m).
        start_position, start_quaternion, end_position, end_quaternion: the fixed start and end.
        via_offset: the window via points' distance before / after the window centre (m).
        length_weight, jerk_weight, jerk_steps: the beam task's cost terms.
        collision_substeps, position_tol, angle_tol: the success check (m, rad).
    """

    env_low: tuple = (0.5, -0.15, 0.45, math.radians(0.0))
    env_high: tuple = (0.7, 0.15, 0.55, math.radians(40.0))
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
    jerk_steps: int = 1000
    collision_substeps: int = 2
    position_tol: float = 0.05
    angle_tol: float = math.radians(10.0)
    name: str = "teleop_window"
    num_dof: int = 7
    env_dim: int = 4
    num_classes: int = 2
    objective_names: tuple = (
        "start",
        "window_front",
        "window_back",
        "end",
        "q_start",
        "q_window_front",
        "q_window_back",
        "q_end",
    )

    def __post_init__(self) -> None:
        self.env_low, self.env_high = (
            as_vector(self.env_low, "env_low", 4),
            as_vector(self.env_high, "env_high", 4),
        )
        if any(lo > hi for lo, hi in zip(self.env_low, self.env_high)):
            raise ValueError(f"env_low {self.env_low} must be <= env_high {self.env_high}")
        if max(abs(self.env_low[3]), abs(self.env_high[3])) >= math.radians(80):
            raise ValueError(
                "the wall's yaw must stay within +-80 deg (the beam approaches along x)"
            )
        for key in ("start_position", "end_position"):
            setattr(self, key, as_vector(getattr(self, key), key, 3))
        for key in ("start_quaternion", "end_quaternion"):
            q = torch.tensor(as_vector(getattr(self, key), key, 4), dtype=torch.float64)
            setattr(self, key, tuple(float(v) for v in q / q.norm()))
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
        if (
            self.beam_length <= self.window_width
            or self.window_height <= self.beam_length + 2 * self.beam_radius
        ):
            raise ValueError(
                "the beam must be longer than the window is wide and fit upright in its height"
            )
        lo, hi = torch.tensor(self.env_low), torch.tensor(self.env_high)
        for corner in (lo, hi):
            n = torch.tensor([math.cos(corner[3]), math.sin(corner[3]), 0.0], dtype=torch.float64)
            s0 = float((torch.tensor(self.start_position) - corner[:3].double()) @ n)
            s1 = float((torch.tensor(self.end_position) - corner[:3].double()) @ n)
            if not (s0 < -self.via_offset and s1 > self.via_offset):
                raise ValueError(
                    f"the start must lie before and the end after every wall in the range, "
                    f"not so at {corner.tolist()}"
                )

    # ------------------------------------------------------------------ environments
    def check_env(self, env, name: str = "env") -> Tensor:
        """``env (..., 4)`` as a float tensor; a wrong shape or a non-finite value is refused."""
        env = check_tensor(torch.as_tensor(env), name)
        if env.shape[-1:] != (4,):
            raise ValueError(
                f"{name} must be (..., 4) = wall x, y, z, yaw; got shape {tuple(env.shape)}"
            )
        return env if env.is_floating_point() else env.double()

    def sample_envs(
        self, n: int, generator: torch.Generator, dtype: torch.dtype = torch.float64
    ) -> Tensor:
        """``n`` wall poses ``(n, 4)`` uniform in ``[env_low, env_high]``."""
        lo, hi = torch.tensor(self.env_low, dtype=dtype), torch.tensor(self.env_high, dtype=dtype)
        return lo + (hi - lo) * torch.rand(int(n), 4, generator=generator, dtype=dtype)

    def clamp_env(self, env: Tensor) -> Tensor:
        """``env (..., 4)`` clipped to the trained range."""
        lo, hi = (
            torch.tensor(v, dtype=env.dtype, device=env.device)
            for v in (self.env_low, self.env_high)
        )
        return torch.maximum(torch.minimum(env, hi), lo)

    def wall_frame(self, env: Tensor) -> tuple[Tensor, Tensor]:
        """Centre ``(..., 3)`` and rotation ``(..., 3, 3)`` (columns: normal, width, height)."""
        yaw = env[..., 3]
        c, s = torch.cos(yaw), torch.sin(yaw)
        z, o = torch.zeros_like(c), torch.ones_like(c)
        rot = torch.stack(
            [torch.stack([c, -s, z], -1), torch.stack([s, c, z], -1), torch.stack([z, z, o], -1)],
            -2,
        )
        return env[..., :3], rot

    def passing_quaternions(self, env: Tensor) -> Tensor:
        """``(..., 2, 4)``: the beam upright in the window, rolled +90 deg (class 0) or -90 deg
        (class 1) about the normal from lying along the window's width."""
        kw = dict(dtype=env.dtype, device=env.device)
        qz = quaternion_about((0, 0, 1), math.pi / 2, **kw)
        local = torch.stack(
            [
                quaternion_raw_multiply(quaternion_about((1, 0, 0), sgn * math.pi / 2, **kw), qz)
                for sgn in (1.0, -1.0)
            ]
        )  # (2, 4)
        qw = yaw_quaternion(env[..., 3])[..., None, :]  # (..., 1, 4)
        return quaternion_raw_multiply(
            qw.expand(*qw.shape[:-2], 2, 4), local.expand(*qw.shape[:-2], 2, 4)
        )

    def via_positions(self, env: Tensor) -> Tensor:
        """``(..., 4, 3)``: start, before the window, after it, end."""
        c, rot = self.wall_frame(env)
        a = rot[..., 0]  # (..., 3) the normal, from the start's side to the end's
        start = torch.tensor(self.start_position, dtype=env.dtype, device=env.device).expand_as(c)
        end = torch.tensor(self.end_position, dtype=env.dtype, device=env.device).expand_as(c)
        return torch.stack([start, c - self.via_offset * a, c + self.via_offset * a, end], -2)

    def endpoint_poses(self, dtype=torch.float64, device=None) -> tuple[Tensor, Tensor]:
        """The start and end poses ``(7,)``."""
        kw = dict(dtype=dtype, device=device)
        return (
            torch.tensor(self.start_position + self.start_quaternion, **kw),
            torch.tensor(self.end_position + self.end_quaternion, **kw),
        )

    # ------------------------------------------------------------------ collision
    def collides_at(self, poses: Tensor, env: Tensor) -> Tensor:
        """Whether the beam at ``poses (..., 7)`` meets the wall at ``env (..., 4)`` (broadcast):
        ``(...)`` bool. A segment against the slab (inflated by the beam's radius) minus the window
        prism, exact (see :meth:`BeamWindowTask.collides_at`)."""
        q = poses[..., 3:] / _norm(poses[..., 3:]).clamp_min(1e-12)[..., None]
        w, x, y, z = q.unbind(-1)
        axis = torch.stack(
            [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], -1
        )  # (..., 3)
        half = 0.5 * self.beam_length * axis
        c, rot = self.wall_frame(env.to(poses))
        a_l = ((poses[..., :3] - half - c)[..., None, :] @ rot)[
            ..., 0, :
        ]  # (..., 3) in the wall frame
        b_l = ((poses[..., :3] + half - c)[..., None, :] @ rot)[..., 0, :]
        (ax, ay, az), (bx, by, bz) = a_l.unbind(-1), b_l.unbind(-1)
        h = 0.5 * self.wall_thickness + self.beam_radius
        half_w, half_h = (
            0.5 * self.window_width - self.beam_radius,
            0.5 * self.window_height - self.beam_radius,
        )
        dx = bx - ax
        moving = dx != 0
        safe = torch.where(moving, dx, torch.ones_like(dx))
        t1, t2 = (-h - ax) / safe, (h - ax) / safe
        inside = ax.abs() < h
        t_in = torch.where(
            moving, torch.minimum(t1, t2).clamp_min(0), torch.where(inside, 0.0, 1.0).to(dx)
        )
        t_out = torch.where(
            moving, torch.maximum(t1, t2).clamp_max(1), torch.where(inside, 1.0, 0.0).to(dx)
        )

        def in_window(t: Tensor) -> Tensor:
            return ((ay + t * (by - ay)).abs() < half_w) & ((az + t * (bz - az)).abs() < half_h)

        return (t_in < t_out) & ~(in_window(t_in) & in_window(t_out))

    def collides(self, traj: Tensor, env: Tensor) -> Tensor:
        """Whether the beam meets the (static) wall ``env (..., 4)`` anywhere along ``traj (..., T,
        7)``."""
        k, t = self.collision_substeps, traj.shape[-2]
        dense = traj if k == 1 or t < 2 else resample_poses(traj, (t - 1) * k + 1)
        return self.collides_at(dense, env[..., None, :]).any(-1)

    # ------------------------------------------------------------------ objectives
    def _phases(self, pos: Tensor, via: Tensor) -> Tensor:
        """Indices ``(..., 2)`` of the closest approach to the two window via points."""
        return torch.stack([_norm(pos - via[..., i, None, :]).argmin(-1) for i in (1, 2)], -1)

    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """``traj (..., T, 7)``, ``env (..., 4)`` -> ``(..., 8)`` (module docstring)."""
        traj = normalize_poses(traj, "traj")
        env = self.check_env(env).to(traj)
        pos, q = traj[..., :3], align_quaternions(traj[..., 3:])
        via = self.via_positions(env)  # (..., 4, 3)
        d_front = _norm(pos - via[..., 1, None, :]).amin(-1)
        d_back = _norm(pos - via[..., 2, None, :]).amin(-1)
        d_pos = torch.stack(
            [
                _norm(pos[..., 0, :] - via[..., 0, :]),
                d_front,
                d_back,
                _norm(pos[..., -1, :] - via[..., 3, :]),
            ],
            -1,
        )  # (..., 4)
        idx = self._phases(pos, via)  # (..., 2)
        at = q.gather(-2, idx[..., None].expand(*idx.shape, 4))  # (..., 2, 4) at the window phases
        qp = self.passing_quaternions(env)  # (..., 2 classes, 4)
        d_win = quaternion_distance(at[..., None, :, :], qp[..., :, None, :])  # (..., class, phase)
        d_win = d_win.gather(
            -2, d_win.sum(-1).argmin(-1)[..., None, None].expand(*d_win.shape[:-2], 1, 2)
        )[..., 0, :]
        start, end = self.endpoint_poses(traj.dtype, traj.device)
        d_rot = torch.cat(
            [
                quaternion_distance(q[..., 0, :], start[3:])[..., None],
                d_win,
                quaternion_distance(q[..., -1, :], end[3:])[..., None],
            ],
            -1,
        )  # (..., 4)
        length = _norm(pos[..., 1:, :] - pos[..., :-1, :]).sum(-1)
        extra_p = self.length_weight * length + self.jerk_weight * _jerk(pos, self.jerk_steps)
        extra_q = self.length_weight * quaternion_path_length(q) + self.jerk_weight * _jerk(
            q, self.jerk_steps
        )
        return torch.cat([d_pos + extra_p[..., None], d_rot + extra_q[..., None]], -1)

    def label(self, traj: Tensor, env: Tensor) -> Tensor:
        """The class ``(...)`` long of ``traj (..., T, 7)``: the passing orientation closer to the
        beam's at the closest approach to the window centre."""
        traj = normalize_poses(traj, "traj")
        env = self.check_env(env).to(traj)
        c, _ = self.wall_frame(env)
        i = _norm(traj[..., :3] - c[..., None, :]).argmin(-1)  # (...)
        q = traj.gather(-2, i[..., None, None].expand(*i.shape, 1, 7))[..., 0, 3:]  # (..., 4)
        return quaternion_distance(q[..., None, :], self.passing_quaternions(env)).argmin(-1)

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        """Start and end within the tolerances and no collision: ``(...)`` bool."""
        traj = normalize_poses(traj, "traj")
        env = self.check_env(env).to(traj)
        start, end = self.endpoint_poses(traj.dtype, traj.device)
        ok = self.at_pose(traj[..., 0, :], start) & self.at_pose(traj[..., -1, :], end)
        return ok & ~self.collides(traj, env)

    def at_pose(self, pose: Tensor, target: Tensor) -> Tensor:
        """Whether ``pose (..., 7)`` is within the tolerances of ``target (7,)``: ``(...)`` bool."""
        return (_norm(pose[..., :3] - target[:3]) <= self.position_tol) & (
            quaternion_distance(pose[..., 3:], target[3:]) <= self.angle_tol
        )
