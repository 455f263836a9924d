"""The robot experiment of the paper's Sec. IV-C: an arm reaches a target on a table while
avoiding a can, the ProMP in joint space, the objectives on the end-effector path.

Geometry (metres, the robot's base frame: the table top is ``z = 0``, the arm faces ``+x``):

* the arm: the task's robot (:class:`~protorch.robots.Robot`, default the Franka Emika Panda
  shipped with protorch), end effector its end link (the tool centre point); fixed start
  configuration the robot's home (the Panda's puts its end effector ``s`` 10 cm above the table
  at ``(0.40, 0.00)``, hand pointing down);
* the can: a vertical cylinder of Pringles size (radius 3.75 cm, height 23 cm) standing on the
  table at ``(can_x, can_y)``;
* the target: the point ``(goal_x, goal_y)`` at the start's height above the table;
* environment ``e = (can_x, can_y, goal_x, goal_y)``, sampled uniformly over the rectangles
  ``can in [0.50, 0.62] x [-0.12, 0.12]`` and ``goal in [0.66, 0.74] x [-0.24, 0.24]`` (can and
  target at least 12 cm from each other and from the start), or with ``region="table"`` over the
  whole table within the arm's reach (:mod:`protorch.tasks.arm.workspace`); anything off the
  table ``[0.2, 0.9] x [-0.5, 0.5]`` is refused.

Objectives (the paper's, on the end-effector path ``p(t)`` of a joint trajectory ``(..., T, J)``,
evaluated on ``cost_steps`` evenly spaced steps; ``d`` is the mean distance of ``p(t)`` to the
straight segment from ``s`` to the target ``g``)::

    start  ||p(0) - s|| + d
    can    max(-min_t ||p_xy(t) - can||, -0.2) + 0.2 + d      (shifted by 0.2 to be >= 0)
    goal   ||p(T) - g|| + d

(``can_objective`` ``"skeleton"`` / ``"volume"``: the skeleton's / capsules' distance instead,
:mod:`.arm_collision`.)

Success (:meth:`ArmReachTask.success`, every step of the trajectory): the end effector starts within
2 cm of ``s`` and ends within 2 cm of ``g``; the arm stays more than ``margin`` (2 cm for the
skeleton, 1 cm for the exact volumes) from the
can's surface and above the table, under the collision model ``collision``
(:mod:`protorch.tasks.arm.collision`): ``"skeleton"`` (the segments between consecutive frame
origins, base to tool centre point) or ``"volume"`` (the robot's link capsules, the volumes the
MuJoCo scene collides with); every joint stays inside its limits.

Homotopy class (:meth:`ArmReachTask.side`): the signed angle the vector from the can's axis to
the end effector sweeps along the path; negative (clockwise seen from above) is
:data:`LEFT` (the path passes the can on its ``+y`` side for a motion along ``+x``), positive
:data:`RIGHT`. Averaging a left and a right solution drives through the can; the experiment keeps
the two classes apart in the GP map.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ...checks import check_tensor
from ...robots import Robot, load_robot
from ...robots.layout import auto_workspace
from ..base import Task
from .collision import (
    CAN_OBJECTIVES,
    above_table,
    capsule_plan,
    check_collision,
    check_volumes,
    end_capsules,
    end_volume_near,
    frames_gap,
    joints_clearance,
)
from .demos import follow_path, ik_demonstrations, straight_paths
from .deviation import DEVIATIONS, deviation
from .geometry import LEFT, RIGHT, SIDES, broadcast_shape, down_rotation, segment_axis_distance
from .workspace import (
    check_workspace,
    prior_grid_nodes,
)
from .workspace import (
    sample_envs as sample_region,
)
from .workspace import (
    valid_envs as valid_in_region,
)

__all__ = ["ArmReachTask", "LEFT", "RIGHT", "SIDES", "segment_axis_distance", "down_rotation"]


@dataclass
class ArmReachTask(Task):
    """The arm-reaching task (module docstring). Every method is batched: joint trajectories
    ``(..., T, J)`` and environments ``(..., 4)`` broadcast over their leading dimensions (for
    samples ``(B, S, T, J)`` of ``B`` environments ``(B, 4)`` pass ``env[:, None]``).

    Args:
        can_radius, can_height: the can (a Pringles can: 3.75 cm, 23 cm).
        margin: clearance of the arm (under ``collision``) to the can's surface for success;
            ``None``: 2 cm for the skeleton, 1 cm for the volumes (the exact bodies need slack for
            tracking only; at 2 cm the hand held at its start yaw cannot stand at 16 % of the
            sampled targets at all, at 1 cm at 2 %: docs/physics.md).
        collision: ``"skeleton"`` or ``"volume"`` (:mod:`protorch.tasks.arm.collision`).
        clearance: the ``0.2`` of the paper's can objective ``max(-min_t ||p - can||, -0.2)``.
        goal_tol, start_tol: success radii of the end effector at the end and at the start.
        cost_steps: time steps the objectives are evaluated on (evenly spaced, first and last
            included; ``None``: all). Success always uses every step.
        can_box, goal_box: the sampler's rectangles; ``table``: the table top, outside which an
            environment is refused; ``min_separation``: between can, target and start. Each of
            these, ``can_radius``, ``can_height`` and ``reach`` may be ``"auto"`` (the default):
            the Panda's numbers for a shipped robot, for any other arm placed on its own reach
            (:func:`protorch.robots.layout.hand_down_layout`); ``reach`` alone ``"auto"`` (the
            rest given) is the Panda's ``(0.30, 0.80)``.
        region: where :meth:`sample_envs` draws: ``"rectangles"`` (``can_box``, ``goal_box``) or
            ``"table"`` (the whole table, targets within ``reach``, the can clear of the start
            posture); ``reach``: ``(r_min, r_max)``, the targets' horizontal distance from the
            base's axis that the hand-down arm reaches (:mod:`protorch.tasks.arm.workspace`).
        robot: the arm: a :class:`~protorch.robots.Robot`, a shipped robot's name or a dict of
            ``robot.*`` settings (:func:`~protorch.robots.load_robot`); default the Panda.
        start_q: the fixed start configuration (one angle per joint); ``None``: the robot's home.
    """

    can_radius: float | str = "auto"
    can_height: float | str = "auto"
    margin: float | None = None
    clearance: float = 0.2
    goal_tol: float = 0.02
    start_tol: float = 0.02
    cost_steps: int | None = 25
    can_box: tuple | str = "auto"
    goal_box: tuple | str = "auto"
    table: tuple | str = "auto"
    min_separation: float = 0.12
    region: str = "rectangles"
    reach: tuple | str = "auto"
    robot: Robot | str | dict | None = None
    start_q: tuple | None = None
    deviation: str = (
        "segment"  # "time": to tau_direct(t) at the same instant (protorch.tasks.arm.deviation)
    )
    collision: str = "skeleton"  # "volume": the link capsules (protorch.tasks.arm.collision)
    # ee | volume (the hand's, forearm's capsules) | skeleton | auto: as `collision` plans
    can_objective: str = "auto"
    name: str = "arm_reach"
    objective_names: tuple[str, ...] = field(default=("start", "can", "goal"), init=False)
    env_names: tuple[str, ...] = field(default=("can_x", "can_y", "goal_x", "goal_y"), init=False)

    def __post_init__(self) -> None:
        self.robot = load_robot(self.robot)
        self._auto_workspace()
        if self.deviation not in DEVIATIONS:
            raise ValueError(f"deviation must be one of {list(DEVIATIONS)}, got {self.deviation!r}")
        for name in ("can_radius", "can_height", "clearance", "goal_tol", "start_tol"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")
        if self.margin is None:
            self.margin = 0.01 if self.collision == "volume" else 0.02
        if not (math.isfinite(float(self.margin)) and float(self.margin) >= 0):
            raise ValueError(f"margin must be >= 0, got {self.margin!r}")
        if self.cost_steps is not None and (
            isinstance(self.cost_steps, bool) or int(self.cost_steps) < 2
        ):
            raise ValueError(f"cost_steps must be None or an int >= 2, got {self.cost_steps!r}")
        check_workspace(self)
        check_collision(self.collision)
        if self.can_objective not in (*CAN_OBJECTIVES, "auto"):
            raise ValueError(
                f"can_objective must be one of {', '.join(CAN_OBJECTIVES)}, auto, got "
                f"{self.can_objective!r}"
            )
        if self.can_objective == "auto":
            self.can_objective = "volume" if self.collision == "volume" else "ee"
        self.kinematics = self.robot.kinematics()
        if "volume" in (self.collision, self.can_objective):
            check_volumes(self.robot, self.kinematics.frame_names)
        self.end_capsules = (
            end_capsules(self.kinematics, self.robot) if self.can_objective == "volume" else None
        )
        volume = (
            self.collision == "volume"
        )  # the success check's capsules, placed by the compiled kinematics
        self.capsule_plan = (
            capsule_plan(self.kinematics, self.robot.capsule_list()) if volume else None
        )
        self.capsule_radii = torch.tensor(
            [c.radius for c in self.robot.capsule_list()], dtype=torch.float64
        )
        if self.start_q is None:
            self.start_q = self.robot.home
        q0 = torch.tensor(self.start_q, dtype=torch.float64)
        if q0.shape != (self.kinematics.num_joints,):
            raise ValueError(
                f"start_q must have {self.kinematics.num_joints} joint angles, got "
                f"{len(self.start_q)}"
            )
        if not bool(self.kinematics.within_limits(q0)):
            raise ValueError(f"start_q {self.start_q} is outside the joint limits")
        self.start_q = tuple(float(v) for v in self.start_q)
        self.start = tuple(self.kinematics.ee_position(q0).tolist())  # s, (3,)
        if self.start[2] <= 0:
            raise ValueError(
                f"start_q puts the end effector below the table (z = {self.start[2]:.3f})"
            )

    def _auto_workspace(self) -> None:
        """Resolve every ``"auto"`` workspace field (class docstring); the measured layout, where
        one was used, in ``self.layout``."""
        keys = ("can_box", "goal_box", "table", "can_radius", "can_height", "reach")
        self.layout = None
        if not any(isinstance(getattr(self, k), str) and getattr(self, k) == "auto" for k in keys):
            return
        auto = {k for k in keys if isinstance(getattr(self, k), str) and getattr(self, k) == "auto"}
        if auto == {
            "reach"
        }:  # the rest given: no measurement, the Panda's reach (read by region=table only)
            values = {"reach": (0.30, 0.80)}
        else:
            values, self.layout = auto_workspace(self.robot)
        for k in keys:
            if isinstance(getattr(self, k), str) and getattr(self, k) == "auto":
                setattr(self, k, values[k])
        if self.layout is not None:
            logging.getLogger(__name__).info(
                "workspace auto for %s (its hand-down reach %s m at %.3f m): %s",
                self.robot.name,
                self.layout["reach"],
                self.layout["height"],
                ", ".join(f"{k}={getattr(self, k)}" for k in sorted(auto)),
            )

    # ---------------------------------------------------------------- sizes
    @property
    def env_dim(self) -> int:
        return 4

    @property
    def num_dof(self) -> int:
        return self.kinematics.num_joints

    @property
    def ee_height(self) -> float:
        """Height of the start and of the target point above the table."""
        return self.start[2]

    def to(self, device=None) -> "ArmReachTask":
        """Move the kinematic chain (the task's only tensors) to ``device``; returns ``self``."""
        self.kinematics.to(device=device)
        return self

    def start_config(self, dtype=torch.float64, device=None) -> Tensor:
        """The start configuration ``(J,)``."""
        return torch.tensor(self.start_q, dtype=dtype, device=device)

    def start_position(self, dtype=torch.float64, device=None) -> Tensor:
        """``s``, the end effector at the start configuration: ``(3,)``."""
        return torch.tensor(self.start, dtype=dtype, device=device)

    def goal_point(self, env: Tensor) -> Tensor:
        """The target ``g`` of environments ``(..., 4)``: ``(..., 3)``."""
        return torch.cat([env[..., 2:4], torch.full_like(env[..., :1], self.ee_height)], -1)

    # ---------------------------------------------------------- environments
    def check_envs(self, env, name: str = "env") -> Tensor:
        """``env (..., 4)`` as a floating tensor; refuses NaN, the wrong width and anything off
        the table (naming the environment and the coordinate)."""
        env = check_tensor(env, name, ndim_min=1)
        if env.shape[-1] != 4:
            raise ValueError(
                f"{name} must be (..., 4) = (can_x, can_y, goal_x, goal_y), got shape "
                f"{tuple(env.shape)}"
            )
        if not env.is_floating_point():
            env = env.to(torch.float64)
        (x0, x1), (y0, y1) = self.table
        lo = env.new_tensor([x0, y0, x0, y0])
        hi = env.new_tensor([x1, y1, x1, y1])
        off = (env < lo) | (env > hi)  # (..., 4)
        if bool(off.any()):
            idx = [int(i) for i in off.nonzero()[0]]
            k = idx[-1]
            raise ValueError(
                f"{name}{list(idx[:-1])} has {self.env_names[k]} = {float(env[tuple(idx)]):.4g}, "
                "off the table "
                f"x in [{x0}, {x1}], y in [{y0}, {y1}]"
            )
        return env

    def sample_envs(
        self,
        n: int,
        generator: torch.Generator | None = None,
        *,
        dtype: torch.dtype = torch.float64,
        device=None,
        region: str | None = None,
    ) -> Tensor:
        """``n`` environments ``(n, 4)``: uniform over ``region`` (default the task's: can and
        target in their rectangles), redrawn until :meth:`valid_envs`. Drawn in float64 on the
        CPU (``generator`` a CPU generator), then moved."""
        return sample_region(
            self, n, generator, self.region if region is None else region, dtype, device
        )

    def valid_envs(self, env: Tensor, region: str | None = None) -> Tensor:
        """Whether environments are valid in ``region`` (default the task's): can, target and
        start ``min_separation`` apart, and on the table the target within ``reach`` and the can
        clear of the start posture: ``(...)`` bool."""
        return valid_in_region(self, env, self.region if region is None else region)

    def prior_grid(self, n: int = 2004, over: str = "rectangles") -> Tensor:
        """``n`` environments on a regular grid over the region ``over`` ``(n, 4)``: the smallest
        ``k^4`` grid with at least ``n`` valid nodes, of which ``n`` evenly spaced ones
        (lexicographic order) are kept (:func:`protorch.tasks.arm.workspace.prior_grid_nodes`
        also returns the counts)."""
        return prior_grid_nodes(self, n, over)[0]

    # ---------------------------------------------------------------- inputs
    def _prepare(self, traj, env, *, finite: bool = True) -> tuple[Tensor, Tensor]:
        """Check ``traj (..., T, J)`` and ``env (..., 4)``; broadcast their leading dims.
        ``finite=False`` skips the pass over ``traj`` for NaN (the caller checks its result)."""
        if finite or not isinstance(traj, Tensor):
            traj = check_tensor(traj, "traj", ndim_min=2)
        elif traj.ndim < 2:
            raise ValueError(f"traj must have at least 2 dimensions, got shape {tuple(traj.shape)}")
        if traj.shape[-1] != self.num_dof:
            raise ValueError(
                f"traj must be (..., T, {self.num_dof}) joint trajectories of the "
                f"{self.num_dof}-joint arm, "
                f"got shape {tuple(traj.shape)}"
            )
        env = self.check_envs(env)
        if traj.device != env.device:
            raise ValueError(f"traj is on {traj.device} but env is on {env.device}")
        dtype = torch.promote_types(traj.dtype, env.dtype)
        if not dtype.is_floating_point:
            dtype = torch.get_default_dtype()
        try:
            batch = broadcast_shape(traj.shape[:-2], env.shape[:-1])
        except ValueError:
            raise ValueError(
                f"leading dimensions of traj {tuple(traj.shape)} (..., T, J) and env "
                f"{tuple(env.shape)} (..., 4) do not broadcast"
            ) from None
        return traj.to(dtype).expand(*batch, *traj.shape[-2:]), env.to(dtype).expand(*batch, 4)

    def cost_indices(self, num_steps: int) -> Tensor:
        """The time steps the objectives use: ``(T',)`` long."""
        if self.cost_steps is None or self.cost_steps >= num_steps:
            return torch.arange(num_steps)
        return torch.linspace(0, num_steps - 1, int(self.cost_steps)).round().long().unique()

    # ------------------------------------------------------------- geometry
    def ee_path(self, traj: Tensor) -> Tensor:
        """End-effector positions of ``traj (..., T, J)``: ``(..., T, 3)`` (compiled FK)."""
        return self.kinematics.ee_position(traj)

    def ee_from_kinematics(self) -> bool:
        """Whether :meth:`ee_path` is :attr:`kinematics`' end effector (a subclass did not
        override it): a caller may then compute it with its own compiled copy of the kinematics
        (:class:`~protorch.policy.policy.Policy` does)."""
        return type(self).ee_path is ArmReachTask.ee_path

    def side(self, traj: Tensor, env: Tensor) -> Tensor:
        """Homotopy class of the end-effector path around the can: :data:`LEFT` (0) or
        :data:`RIGHT` (1), ``(...)`` long; every step is used (module docstring)."""
        traj, env = self._prepare(traj, env)
        return self.side_of_path(self.ee_path(traj), env)

    def side_of_path(self, path: Tensor, env: Tensor) -> Tensor:
        """:meth:`side` from end-effector paths ``(..., T, 3)`` (or ``(..., T, 2)``)."""
        v = path[..., :2] - env[..., None, 0:2]  # (..., T, 2)
        a, b = v[..., :-1, :], v[..., 1:, :]  # (..., T-1, 2)
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        dot = (a * b).sum(-1)
        swept = torch.atan2(cross, dot).sum(-1)  # (...) signed angle around the can
        return (swept > 0).long()

    def can_distance(self, traj: Tensor, env: Tensor) -> Tensor:
        """Smallest distance between the arm's skeleton and the can's axis segment over all
        steps and segments: ``(...)`` (success needs ``> can_radius + margin``)."""
        traj, env = self._prepare(traj, env)
        links = self.kinematics.link_positions(traj)  # (..., T, F, 3)
        return self.skeleton_distance(links, env)

    def skeleton_distance(self, links: Tensor, env: Tensor) -> Tensor:
        """Smallest distance between skeletons ``links (..., T, F, 3)`` (frame origins, e.g.
        ``kinematics.link_positions``) and the can's axis segment of ``env (..., 4)``: ``(...)``."""
        a, b = links[..., :-1, :], links[..., 1:, :]  # (..., T, F-1, 3)
        axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
        d = segment_axis_distance(a, b, axis, 0.0, self.can_height)  # (..., T, F-1)
        return d.flatten(-2).amin(-1)

    # ------------------------------------------------------------- objectives
    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """``traj (..., T, J)``, ``env (..., 4)`` -> ``(..., 3)`` costs, each >= 0 (module
        docstring)."""
        traj, env = self._prepare(
            traj, env, finite=False
        )  # the hot path: NaN is caught on the costs
        idx = self.cost_indices(traj.shape[-2]).to(traj.device)
        if idx.numel() < traj.shape[-2]:
            traj = traj.index_select(-2, idx)
        if self.can_objective == "skeleton":
            links = self.kinematics.skeleton(
                traj
            )  # (..., T', F, 3), the last frame the end effector
            c = self.path_costs(links[..., -1, :], env, near=self.skeleton_distance(links, env))
        elif self.end_capsules is None:
            c = self.path_costs(self.ee_path(traj), env)  # (..., 3)
        else:
            near, path = end_volume_near(
                self.kinematics, traj, env, self.end_capsules, self.can_height
            )
            c = self.path_costs(path, env, near=near.amin(-1))
        if not bool(torch.isfinite(c).all()):
            raise ValueError("traj contains NaN or inf values (its costs are not finite)")
        return c

    def objective_cost(self, traj: Tensor, env: Tensor, index: int) -> Tensor:
        """Objective ``index`` of :meth:`costs` alone, ``(...)`` (the loop asks when PRO's update
        reads one objective): with ``can_objective="volume"`` only the can objective pays for the
        arm's capsules (``"skeleton"``: its skeleton), the start and goal objectives the end
        effector."""
        if index not in (0, 1, 2):
            raise ValueError(f"index must be 0, 1 or 2, got {index!r}")
        if index == 1 or self.can_objective == "ee":
            return self.costs(traj, env)[..., index]
        traj, env = self._prepare(traj, env, finite=False)
        idx = self.cost_indices(traj.shape[-2]).to(traj.device)
        return self.path_costs(self.ee_path(traj.index_select(-2, idx)), env)[..., index]

    def path_costs(
        self, path: Tensor, env: Tensor, start: Tensor | None = None, near: Tensor | None = None
    ) -> Tensor:
        """The objectives of end-effector paths ``(..., T, 3)``: ``(..., 3)``. ``start (..., 3)``
        replaces ``s`` (the online test scores the rest of a motion from where the arm is);
        ``near (...)`` the path's nearest distance to the can's axis (``can_objective`` volume,
        skeleton)."""
        s = self.start_position(path.dtype, path.device) if start is None else start  # (..., 3)
        s = s.expand(*path.shape[:-2], 3)
        g = self.goal_point(env)  # (..., 3)
        d = deviation(self.deviation, path, s, g).mean(-1)  # (...)
        d_start = (path[..., 0, :] - s).norm(dim=-1)
        d_goal = (path[..., -1, :] - g).norm(dim=-1)
        if near is None:
            near = (path[..., :2] - env[..., None, 0:2]).norm(dim=-1).amin(-1)  # (...)
        can = self.clearance - near.clamp(max=self.clearance)
        return torch.stack([d_start + d, can + d, d_goal + d], -1)

    def can_gap(self, traj: Tensor, env: Tensor) -> Tensor:
        """Smallest distance between the arm's surface (under :attr:`collision`) and the can's over
        all steps: ``(...)`` (success needs ``> margin``;
        :func:`~protorch.tasks.arm.collision.frames_gap`)."""
        traj, env = self._prepare(traj, env)
        if self.capsule_plan is not None:
            return joints_clearance(self, traj, env)[0]
        return frames_gap(self, self.kinematics.frames(traj), env)

    def frames_gap(self, frames: Tensor, env: Tensor) -> Tensor:
        """:meth:`can_gap` from the chain's frames ``(..., T, F, 4, 4)``."""
        return frames_gap(self, frames, env)

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        """Start and end within tolerance, the arm more than ``margin`` from the can and above the
        table (under :attr:`collision`), joint limits respected; every step: ``(...)``."""
        traj, env = self._prepare(traj, env)
        if self.capsule_plan is not None:  # the volumes: the compiled kinematics
            ee = self.kinematics.ee_position(traj)  # (..., T, 3)
            gap, table = joints_clearance(self, traj, env)
        else:
            frames = self.kinematics.frames(traj)  # (..., T, F, 4, 4)
            ee, gap, table = (
                frames[..., -1, :3, 3],
                frames_gap(self, frames, env),
                above_table(self, frames),
            )
        ok_start = (ee[..., 0, :] - self.start_position(ee.dtype, ee.device)).norm(
            dim=-1
        ) <= self.start_tol
        ok_goal = (ee[..., -1, :] - self.goal_point(env)).norm(dim=-1) <= self.goal_tol
        limits = self.kinematics.within_limits(traj).all(-1)
        return ok_start & ok_goal & (gap > self.margin) & limits & table

    # ---------------------------------------------------------------- demonstrations
    def ik_path(
        self, path: Tensor, *, iters: int = 8, first_iters: int = 60
    ) -> tuple[Tensor, Tensor]:
        """Joint trajectories following end-effector paths ``(n, T, 3)`` with the hand pointing
        down (the start configuration's orientation), from the start configuration: damped least
        squares at every step, warm-started
        from the step before, with a null-space pull to the start posture. Returns
        ``(q (n, T, J), position error (n, T))``."""
        return follow_path(self, path, iters=iters, first_iters=first_iters)

    def straight_paths(self, env: Tensor, num_steps: int = 100) -> Tensor:
        """The straight end-effector path from ``s`` to the target of each environment, with a
        minimum-jerk time profile: ``(n, num_steps, 3)``."""
        return straight_paths(self, self.check_envs(env).to(torch.float64), num_steps)

    def demonstrations(
        self,
        envs: Tensor | int,
        per_env: int = 3,
        generator: torch.Generator | None = None,
        *,
        sides: Tensor | None = None,
        lengths: tuple[int, int] = (150, 250),
        pass_distance: tuple[float, float] = (0.17, 0.27),
        goal_noise: float = 0.01,
        tremor: float = 0.008,
    ) -> tuple[list[Tensor], Tensor, Tensor]:
        """Imperfect, hand-guided-like demonstrations by inverse kinematics: ``per_env`` per
        environment, all passing the can on the side ``sides[i]`` (default: alternating
        :data:`LEFT`, :data:`RIGHT`); the paths and their parameters are those of
        :func:`~protorch.tasks.arm.demos.ik_demonstrations`. Returns ``(demos, demo_envs, labels)``:
        ``M * per_env`` joint trajectories ``(T_i, J)``,
        their environments ``(M * per_env, 4)`` and the homotopy class of each (measured on
        the joint trajectory with :meth:`side`, not assumed).
        """
        return ik_demonstrations(
            self,
            envs,
            per_env,
            generator,
            sides=sides,
            lengths=lengths,
            pass_distance=pass_distance,
            goal_noise=goal_noise,
            tremor=tremor,
        )
