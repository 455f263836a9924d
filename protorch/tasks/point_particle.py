"""The point-particle task of the paper's Sec. IV-B: a particle in the workspace ``[0, 10]^2``
moves from a start, through the hole of a thick vertical wall, to a goal.

Environment ``e = (start_x, start_y, wall_x, hole_y, goal_x, goal_y)``, as in the authors' data
(marcoewerton/avoid_moving_walls, ``envK.out``). The wall is the two rectangles
``x in [wall_x - 1, wall_x + 1]``, ``y <= hole_y - 1`` and ``y >= hole_y + 1``; the hole is
``y in (hole_y - 1, hole_y + 1)``. With ``fixed_start`` the environment is the paper's 4-D
``(wall_x, hole_y, goal_x, goal_y)`` and the start is a constant.

Every function is batched: environments ``(..., E)`` and trajectories ``(..., T, 2)`` whose
leading dimensions broadcast against each other (numpy rules, aligned from the right: for
samples ``(B, S, T, 2)`` of ``B`` environments ``(B, E)`` pass ``env[:, None]``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..checks import check_tensor
from .base import Task
from .curves import catmull_rom as _catmull_rom
from .curves import smooth_noise as _smooth_noise

__all__ = [
    "PointParticleTask",
    "WORKSPACE",
    "WALL_HALF_WIDTH",
    "HOLE_HALF_HEIGHT",
    "signed_distance_to_wall",
    "wall_collision",
]

WORKSPACE = (0.0, 10.0)  # both axes
WALL_HALF_WIDTH = 1.0  # the wall spans x in [wall_x - 1, wall_x + 1]
HOLE_HALF_HEIGHT = 1.0  # the hole spans y in (hole_y - 1, hole_y + 1)
_MARGIN = 1.5  # sampler: start_x <= wall_x - 1.5, goal_x >= wall_x + 1.5
_PIXEL = 10.0 / 500  # the synthetic mouse's screen resolution, in workspace units

_OBJECTIVES = {"hole": ("start", "hole", "goal"), "clearance": ("start", "clearance", "goal")}


# ----------------------------------------------------------------------------- geometry
def _wall_bounds(env6: Tensor, infinite: bool) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``x_lo, x_hi (...)`` of the wall and ``y_lo, y_hi (..., 2)`` of its lower/upper rectangle."""
    wx, hy = env6[..., 2], env6[..., 3]  # (...)
    lo, hi = WORKSPACE
    bottom, top = (-float("inf"), float("inf")) if infinite else (lo, hi)
    y_lo = torch.stack([torch.full_like(hy, bottom), hy + HOLE_HALF_HEIGHT], -1)  # (..., 2)
    y_hi = torch.stack([hy - HOLE_HALF_HEIGHT, torch.full_like(hy, top)], -1)  # (..., 2)
    return wx - WALL_HALF_WIDTH, wx + WALL_HALF_WIDTH, y_lo, y_hi


def signed_distance_to_wall(points: Tensor, env6: Tensor, *, infinite_wall: bool = True) -> Tensor:
    """Signed Euclidean distance of ``points (..., 2)`` to the wall of ``env6 (..., 6)``: ``(...)``.

    Positive outside the wall, negative inside a rectangle (minus the depth to the nearest face),
    zero on its boundary. The two rectangles are disjoint (2 apart), so the minimum of the two
    box distances is the exact signed distance to their union. No input checks (see the task).
    """
    wx, hy = env6[..., 2], env6[..., 3]  # (...)
    # in place where a temporary is free: the same operations in the same order (the same numbers)
    # with half the allocations (the loop calls this on 10^6 points at a time)
    q_x = torch.sub(points[..., 0], wx).abs_().sub_(WALL_HALF_WIDTH)  # (...)  > 0: beside the wall
    y = points[..., 1]  # (...)
    if infinite_wall:
        # the nearer rectangle is the one on the same side of the hole's centre line, and a box's
        # signed distance grows with its y-distance, so one box term suffices (half the work)
        q_y = (
            torch.sub(y, hy).abs_().neg_().add_(HOLE_HALF_HEIGHT)
        )  # (...)  1 - |y - hy| > 0: in the hole's y-range
        outside = torch.hypot(q_x.clamp_min(0), q_y.clamp_min(0))  # (...)
        inside = torch.maximum(q_x, q_y).clamp_max_(0)  # (...)
        return (
            outside + inside if outside.requires_grad else outside.add_(inside)
        )  # autograd keeps hypot's result
    # box distance along y, > 0 outside the rectangle's y-range: max(y - top, bottom - y)
    q_low = y - (hy - HOLE_HALF_HEIGHT)  # (...)  lower rectangle, top face hole_y - 1
    q_up = (hy + HOLE_HALF_HEIGHT) - y  # (...)  upper rectangle, bottom face hole_y + 1
    if not infinite_wall:
        lo, hi = WORKSPACE
        q_low = torch.maximum(q_low, lo - y)  # (...)
        q_up = torch.maximum(q_up, y - hi)  # (...)
    q_y = torch.stack([q_low, q_up], -1)  # (..., 2)
    q_x = q_x[..., None].expand_as(q_y)  # (..., 2)
    outside = torch.hypot(q_x.clamp_min(0), q_y.clamp_min(0))  # (..., 2)
    inside = torch.maximum(q_x, q_y).clamp_max(0)  # (..., 2)
    return (outside + inside).amin(-1)  # (...)


def _distance(points: Tensor, target: Tensor) -> Tensor:
    """``||points - target||`` over the last axis ``(..., 2)`` -> ``(...)``; the norm's rounding
    depends
    on its input's memory layout: contiguous points make it the same for a trajectory of any
    layout."""
    return (points.contiguous() - target).norm(dim=-1)


def wall_collision(traj: Tensor, env6: Tensor, *, infinite_wall: bool = True) -> Tensor:
    """Whether the polyline ``traj (..., T, 2)`` enters the open interior of a wall rectangle.

    Exact segment-rectangle test (Liang-Barsky clipping of every segment against both
    rectangles), so no resampling is needed: ``(...)`` bool. ``env6 (..., 6)``. A path that only
    touches a face or a corner does not collide (consistent with ``signed_distance < 0``).
    """
    if traj.shape[-2] == 1:
        traj = torch.cat([traj, traj], -2)  # one point: a zero-length segment
    p0, p1 = traj[..., :-1, :], traj[..., 1:, :]  # (..., T-1, 2)
    d = p1 - p0  # (..., T-1, 2)
    x_lo, x_hi, y_lo, y_hi = _wall_bounds(env6, infinite_wall)  # (...), (...), (..., 2), (..., 2)
    # per axis, bounds (..., 1, 2): one column per rectangle, broadcast over segments
    lo = [x_lo[..., None, None], y_lo[..., None, :]]  # (..., 1, 1), (..., 1, 2)
    hi = [x_hi[..., None, None], y_hi[..., None, :]]
    t_enter = torch.zeros((), dtype=traj.dtype, device=traj.device)
    t_exit = torch.ones((), dtype=traj.dtype, device=traj.device)
    inf = torch.tensor(float("inf"), dtype=traj.dtype, device=traj.device)
    for k in range(2):
        a, v = p0[..., k, None], d[..., k, None]  # (..., T-1, 1)
        moving = v != 0  # (..., T-1, 1)
        safe = torch.where(moving, v, torch.ones_like(v))  # (..., T-1, 1)
        t1, t2 = (lo[k] - a) / safe, (hi[k] - a) / safe  # (..., T-1, 1 or 2)
        still_in = (lo[k] < a) & (
            a < hi[k]
        )  # (..., T-1, 1 or 2)  a static coordinate inside the slab
        t_lo = torch.where(moving, torch.minimum(t1, t2), torch.where(still_in, -inf, inf))
        t_hi = torch.where(moving, torch.maximum(t1, t2), torch.where(still_in, inf, -inf))
        t_enter, t_exit = torch.maximum(t_enter, t_lo), torch.minimum(t_exit, t_hi)  # (..., T-1, 2)
    return (t_enter < t_exit).flatten(-2).any(-1)  # (...)


# ----------------------------------------------------------------------------- the task
@dataclass
class PointParticleTask(Task):
    """Objectives on a trajectory ``(..., T, 2)`` in an environment ``(..., E)``: ``(..., 3)``.

    ``objectives="hole"`` (the paper): distance of ``tau(0)`` to the start, minimum over ``t`` of
    the distance to the hole centre ``(wall_x, hole_y)``, distance of ``tau(T)`` to the goal.

    ``objectives="clearance"`` (the authors' code): the middle objective becomes the negative
    minimum signed distance of the path to the wall, shifted by the hole's half-height:
    ``max(1 - min_t sd(tau(t)), 0)``. No path that crosses the wall line ``x = wall_x`` can have a
    clearance above 1 (the hole is 2 high), so the shift makes the cost >= 0, and 0 only for a
    path that crosses the hole along its centre line ``y = hole_y``; being a constant it leaves
    PRO's rewards unchanged
    (``exp(-beta * o)`` is shifted by its minimum anyway), so this ranks samples exactly as the
    authors' objective. The clamp only acts for a path that jumps over the wall between two samples
    (or goes around a wall bounded by the workspace).

    Args:
        objectives: ``"hole"`` or ``"clearance"``.
        fixed_start: ``(x, y)`` to use the paper's 4-D environment ``(wall_x, hole_y, goal_x,
            goal_y)`` with this start; ``None`` (default) for the authors' 6-D environment.
        infinite_wall: the wall continues beyond ``y = 0`` and ``y = 10`` (default), so a path
            cannot go around it by leaving the workspace. Inside the workspace the geometry is the
            authors' rectangles (the signed distance differs only in the depth of points inside
            the wall near ``y = 0, 10``). ``False`` uses the rectangles clipped to ``[0, 10]``.
    """

    objectives: str = "hole"
    fixed_start: tuple[float, float] | None = None
    infinite_wall: bool = True
    name: str = "point_particle"
    objective_names: tuple[str, ...] = field(default=(), init=False)

    def __post_init__(self) -> None:
        if self.objectives not in _OBJECTIVES:
            raise ValueError(
                f"objectives must be one of {sorted(_OBJECTIVES)}, got {self.objectives!r}"
            )
        self.objective_names = _OBJECTIVES[self.objectives]
        if self.fixed_start is not None:
            start = tuple(float(v) for v in self.fixed_start)
            lo, hi = WORKSPACE
            if len(start) != 2 or not (lo <= start[0] <= 8.0 - _MARGIN and lo <= start[1] <= hi):
                raise ValueError(
                    "fixed_start must be (x, y) with 0 <= x <= 6.5 (a wall at x <= 8 must fit 1.5 "
                    f"to its right) and 0 <= y <= 10, got {start}"
                )
            self.fixed_start = (start[0], start[1])

    # ---------------------------------------------------------------- environments
    @property
    def env_dim(self) -> int:
        """``E``: 4 with a fixed start (the paper), else 6 (the authors' data)."""
        return 4 if self.fixed_start is not None else 6

    def full_env(self, env: Tensor) -> Tensor:
        """``(..., 4)`` (with ``fixed_start``) or ``(..., 6)`` -> the 6-D ``(..., 6)``."""
        env = check_tensor(env, "env", ndim_min=1)
        if not env.is_floating_point():
            env = env.to(torch.get_default_dtype())
        if env.shape[-1] == 6:
            return env
        if env.shape[-1] == 4 and self.fixed_start is not None:
            start = env.new_tensor(self.fixed_start).expand(*env.shape[:-1], 2)  # (..., 2)
            return torch.cat([start, env], -1)  # (..., 6)
        allowed = "4 or 6" if self.fixed_start is not None else "6 (4 needs fixed_start)"
        raise ValueError(f"env must have last dimension {allowed}, got shape {tuple(env.shape)}")

    def sample_envs(
        self,
        n: int,
        generator: torch.Generator | None = None,
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> Tensor:
        """``n`` random environments ``(n, env_dim)``, the authors' sampler:
        ``wall_x ~ U(2, 8)``, ``hole_y ~ U(1, 9)``, ``start_x ~ U(0, wall_x - 1.5)``,
        ``start_y ~ U(0, 10)``, ``goal_x ~ U(wall_x + 1.5, 10)``, ``goal_y ~ U(0, 10)``.
        With ``fixed_start`` the wall is drawn from ``U(max(2, start_x + 1.5), 8)`` so the start
        keeps its 1.5 margin. Drawn on the CPU (``generator`` is a CPU generator), then moved.
        """
        if int(n) < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        u = torch.rand(int(n), 6, generator=generator, dtype=torch.float64)  # (n, 6)
        wall_lo = 2.0 if self.fixed_start is None else max(2.0, self.fixed_start[0] + _MARGIN)
        wx = wall_lo + (8.0 - wall_lo) * u[:, 0]  # (n,)
        hy = 1.0 + 8.0 * u[:, 1]  # (n,)
        sx = (wx - _MARGIN) * u[:, 2]  # (n,)
        sy = 10.0 * u[:, 3]  # (n,)
        gx = wx + _MARGIN + (10.0 - wx - _MARGIN) * u[:, 4]  # (n,)
        gy = 10.0 * u[:, 5]  # (n,)
        env = torch.stack([sx, sy, wx, hy, gx, gy], -1)  # (n, 6)
        if self.fixed_start is not None:
            env = env[:, 2:]  # (n, 4)
        return env.to(dtype=dtype, device=device)

    # ---------------------------------------------------------------- validation
    def _prepare(self, traj: Tensor, env: Tensor) -> tuple[Tensor, Tensor]:
        """Check ``traj (..., T, 2)`` and ``env (..., E)``; return them broadcast to one batch
        shape, in a common floating dtype, with ``env`` expanded to 6-D."""
        traj = check_tensor(traj, "traj", ndim_min=2)
        env = self.full_env(env)  # (..., 6)
        if traj.shape[-1] != 2:
            raise ValueError(f"traj must be (..., T, 2), got shape {tuple(traj.shape)}")
        if traj.shape[-2] < 1:
            raise ValueError(
                f"traj must have at least one time step, got shape {tuple(traj.shape)}"
            )
        if traj.device != env.device:
            raise ValueError(f"traj is on {traj.device} but env is on {env.device}")
        dtype = torch.promote_types(traj.dtype, env.dtype)
        if not dtype.is_floating_point:
            dtype = torch.get_default_dtype()
        try:  # numpy's rule; torch.broadcast_shapes imports sympy on first use (~2 s per process)
            batch = np.broadcast_shapes(tuple(traj.shape[:-2]), tuple(env.shape[:-1]))
        except ValueError:
            raise ValueError(
                f"leading dimensions of traj {tuple(traj.shape)} (..., T, 2) and env "
                f"{tuple(env.shape)} (..., E) do not broadcast"
            ) from None
        traj = traj.to(dtype).expand(*batch, *traj.shape[-2:])  # (..., T, 2)
        env = env.to(dtype).expand(*batch, 6)  # (..., 6)
        return traj, env

    def _prepare_points(self, points: Tensor, env: Tensor) -> tuple[Tensor, Tensor]:
        points = check_tensor(points, "points", ndim_min=1)
        if points.shape[-1] != 2:
            raise ValueError(f"points must be (..., 2), got shape {tuple(points.shape)}")
        traj, env = self._prepare(points[..., None, :], env)  # a one-step trajectory
        return traj[..., 0, :], env

    # ---------------------------------------------------------------- geometry
    def signed_distance_to_wall(self, points: Tensor, env: Tensor) -> Tensor:
        """``points (..., 2)``, ``env (..., E)`` -> ``(...)``: > 0 outside, < 0 inside the wall.

        For a trajectory ``(..., T, 2)`` pass ``env[..., None, :]``.
        """
        points, env = self._prepare_points(points, env)
        return signed_distance_to_wall(points, env, infinite_wall=self.infinite_wall)

    def clearance(self, traj: Tensor, env: Tensor) -> Tensor:
        """``min_t`` signed distance of the samples of ``traj (..., T, 2)`` to the wall: ``(...)``.
        The authors' convergence check asks for a clearance >= 0.1."""
        traj, env = self._prepare(traj, env)
        sd = signed_distance_to_wall(
            traj, env[..., None, :], infinite_wall=self.infinite_wall
        )  # (..., T)
        return sd.amin(-1)

    def collides(self, traj: Tensor, env: Tensor) -> Tensor:
        """Whether the piecewise-linear path ``traj (..., T, 2)`` enters the wall: ``(...)`` bool.
        Exact between samples (segment-rectangle test)."""
        traj, env = self._prepare(traj, env)
        return wall_collision(traj, env, infinite_wall=self.infinite_wall)

    def wall_rectangles(self, env: Tensor) -> Tensor:
        """The two wall rectangles inside the workspace, for plotting: ``(..., 2, 4)`` as
        ``(x_min, x_max, y_min, y_max)``, lower rectangle first."""
        env = self.full_env(env)  # (..., 6)
        x_lo, x_hi, y_lo, y_hi = _wall_bounds(env, infinite=False)
        x = torch.stack([x_lo, x_hi], -1)[..., None, :].expand(*y_lo.shape, 2)  # (..., 2, 2)
        return torch.cat([x, torch.stack([y_lo, y_hi], -1)], -1)  # (..., 2, 4)

    # ---------------------------------------------------------------- objectives
    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """``traj (..., T, 2)``, ``env (..., E)`` -> ``(..., 3)`` costs, each >= 0 (see
        the class)."""
        traj, env = self._prepare(traj, env)
        d_start = _distance(traj[..., 0, :], env[..., 0:2])  # (...)
        d_goal = _distance(traj[..., -1, :], env[..., 4:6])  # (...)
        if self.objectives == "hole":
            hole = env[..., 2:4]  # (..., 2)  centre (wall_x, hole_y)
            middle = (traj - hole[..., None, :]).norm(dim=-1).amin(-1)  # (...)
        else:
            sd = signed_distance_to_wall(
                traj, env[..., None, :], infinite_wall=self.infinite_wall
            )  # (..., T)
            middle = (HOLE_HALF_HEIGHT - sd.amin(-1)).clamp_min(0)  # (...)
        return torch.stack([d_start, middle, d_goal], -1)  # (..., 3)

    def objective_cost(self, traj: Tensor, env: Tensor, index: int) -> Tensor:
        """Objective ``index`` of :meth:`costs` alone: ``(...)``. The self-improvement loop calls
        it when the optimiser's update reads one objective (PRO's per-objective steps), so the
        start and goal steps do not pay for the path's clearance."""
        if index not in (0, 1, 2):
            raise ValueError(f"index must be 0, 1 or 2, got {index!r}")
        if index == 1:
            return self.costs(traj, env)[..., 1]
        traj, env = self._prepare(traj[..., [0, -1], :], env)  # the two end points suffice
        if index == 0:
            return _distance(traj[..., 0, :], env[..., 0:2])  # (...)
        return _distance(traj[..., -1, :], env[..., 4:6])  # (...)

    def objective_steps(self, index: int) -> tuple[int, ...] | None:
        """The time steps objective ``index`` reads (``None``: all); :meth:`objective_cost` gives
        the same
        number for a trajectory restricted to them (the loop computes only those)."""
        if index not in (0, 1, 2):
            raise ValueError(f"index must be 0, 1 or 2, got {index!r}")
        return None if index == 1 else (0, -1)

    def success(self, traj: Tensor, env: Tensor, tol: float = 0.2) -> Tensor:
        """Start and end within ``tol`` of their targets and the path, between samples as well,
        never inside the wall: ``(...)`` bool."""
        if not tol >= 0:
            raise ValueError(f"tol must be >= 0, got {tol}")
        traj, env = self._prepare(traj, env)
        d_start = _distance(traj[..., 0, :], env[..., 0:2])  # (...)
        d_goal = _distance(traj[..., -1, :], env[..., 4:6])  # (...)
        hit = wall_collision(traj, env, infinite_wall=self.infinite_wall)  # (...)
        return (d_start <= tol) & (d_goal <= tol) & ~hit

    # ---------------------------------------------------------------- demonstrations
    def demonstrations(
        self,
        envs: Tensor | int,
        per_env: int = 3,
        generator: torch.Generator | None = None,
        *,
        lengths: tuple[int, int] = (200, 340),
        hole_noise: float = 0.75,
        endpoint_noise: float = 0.07,
    ) -> tuple[list[Tensor], Tensor]:
        """Imperfect mouse-drawn demonstrations: ``per_env`` per environment.

        Args:
            envs: ``(M, E)`` environments, or an int ``M`` to draw them with :meth:`sample_envs`.
            per_env: demonstrations per environment; demonstration ``per_env * i + j`` belongs to
                environment ``i``, as in the human data.
            generator: CPU generator for every random draw.
            lengths: inclusive range of the number of samples per demonstration.
            hole_noise: std of the operator's vertical aim error at the hole, shared by the three
                via points of one demonstration (each also gets an independent 0.12). With the
                default about a quarter of the demonstrations (20 to 27 % over 600, seeds 0-7) clip
                the wall.
            endpoint_noise: std per coordinate of the start and end errors.

        Returns:
            ``(demos, demo_envs)``: ``M * per_env`` tensors ``(T_i, 2)`` and ``(M * per_env, E)``,
            in the dtype and on the device of ``envs`` (float64 on the CPU for an int).

        Each path is a cubic (Catmull-Rom, chord-length) curve through the jittered start, three
        aim points before, in and after the hole, and the jittered goal; it is traversed with a
        bell-shaped (minimum-jerk) speed profile with a random skew, so samples bunch at the ends
        like mouse events, then gets a smooth hand tremor and is rounded to a 0.02 pixel grid.
        """
        if isinstance(envs, int):
            envs = self.sample_envs(envs, generator)
        envs = check_tensor(envs, "envs", ndim=2)
        env6 = self.full_env(envs).detach().to("cpu", torch.float64)  # (M, 6)
        if int(per_env) < 1:
            raise ValueError(f"per_env must be >= 1, got {per_env}")
        t_min, t_max = int(lengths[0]), int(lengths[1])
        if not 2 <= t_min <= t_max:
            raise ValueError(f"lengths must be (lo, hi) with 2 <= lo <= hi, got {lengths}")
        g, f64 = generator, torch.float64
        e = env6.repeat_interleave(int(per_env), 0)  # (n, 6)
        n = e.shape[0]
        wx, hy = e[:, 2], e[:, 3]  # (n,)
        aim = hole_noise * torch.randn(n, 1, generator=g, dtype=f64)  # (n, 1) the operator's bias
        dy = aim + 0.12 * torch.randn(n, 3, generator=g, dtype=f64)  # (n, 3)
        gap = 0.15 + 0.5 * torch.rand(n, 2, generator=g, dtype=f64)  # (n, 2) beyond the wall faces
        x_via = torch.stack(
            [
                wx - WALL_HALF_WIDTH - gap[:, 0],
                wx + 0.2 * torch.randn(n, generator=g, dtype=f64),
                wx + WALL_HALF_WIDTH + gap[:, 1],
            ],
            -1,
        )  # (n, 3)
        via = torch.cat(
            [
                (e[:, 0:2] + endpoint_noise * torch.randn(n, 2, generator=g, dtype=f64))[:, None],
                torch.stack([x_via, hy[:, None] + dy], -1),
                (e[:, 4:6] + endpoint_noise * torch.randn(n, 2, generator=g, dtype=f64))[:, None],
            ],
            1,
        )  # (n, 5, 2)
        length = torch.randint(t_min, t_max + 1, (n, 1), generator=g)  # (n, 1)
        skew = 0.8 + 0.45 * torch.rand(n, 1, generator=g, dtype=f64)  # (n, 1)
        # demo i uses its first length[i] columns; the rest repeats its last sample
        u = (torch.arange(t_max, dtype=f64) / (length - 1)).clamp(
            max=1
        )  # (n, T_max) time in [0, 1]
        v = u**skew  # (n, T_max)  a slower start or end
        s = v**3 * (10 - 15 * v + 6 * v**2)  # (n, T_max) minimum-jerk progress along the path
        path = _catmull_rom(via, s)  # (n, T_max, 2)
        tremor = _smooth_noise(u, 0.03, g) * torch.sin(torch.pi * s)[..., None]  # (n, T_max, 2)
        path = torch.round((path + tremor) / _PIXEL) * _PIXEL  # (n, T_max, 2)
        path = path.to(dtype=envs.dtype, device=envs.device)
        demos = [p[:t].clone() for p, t in zip(path, length[:, 0].tolist())]  # (T_i, 2) each
        return demos, envs.repeat_interleave(int(per_env), 0)  # list of (T_i, 2), (n, E)
