"""What teaching needs of a task, as plain functions (no browser, no viser): the files'
:class:`~protorch.data.demos.DemoFormat`, environments to propose, the quality checks of one
demonstration, and (the arm) the joint configuration that follows a dragged hand.

:class:`ParticleTeach` checks a drawn point-particle path; :class:`ArmTeach` a joint trajectory
recorded while the hand was dragged; :class:`HandFollower` is that recording's inverse
kinematics (damped least squares from the previous configuration, the hand kept pointing down as
in the start configuration, a null-space pull to the start posture: the project's
:meth:`~protorch.robots.kinematics.ArmKinematics.inverse`, as the arm's synthetic demonstrations).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..data.demos import PARTICLE_FORMAT, DemoFormat
from ..tasks.arm.demos import arm_demo_format
from ..tasks.arm.reach import SIDES, ArmReachTask
from ..tasks.point_particle import PointParticleTask

__all__ = ["ArmTeach", "HandFollower", "ParticleTeach", "Quality", "make_teach_task", "TEACH_TASKS"]


@dataclass
class Quality:
    """The checks of one demonstration: ``flags`` names the failed ones (``start``, ``goal``,
    ``collides``, ``short``; the arm also ``ik``, ``table``, ``side``), ``messages`` says each in
    words, ``values`` holds the measured numbers."""

    flags: tuple[str, ...] = ()
    messages: list[str] = field(default_factory=list)
    values: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.flags

    def fail(self, flag: str, message: str) -> None:
        self.flags = (*self.flags, flag)
        self.messages.append(message)


def _common_checks(
    q: Quality, samples: int, start_d: float, goal_d: float, tol: float, min_samples: int, unit: str
) -> None:
    q.values.update(
        samples=int(samples), start_distance=float(start_d), goal_distance=float(goal_d)
    )
    if samples < min_samples:
        q.fail("short", f"too short: {samples} samples (at least {min_samples})")
    if start_d > tol:
        q.fail("start", f"starts {start_d:.3g}{unit} from the start (tolerance {tol:g}{unit})")
    if goal_d > tol:
        q.fail("goal", f"ends {goal_d:.3g}{unit} from the goal (tolerance {tol:g}{unit})")


class ParticleTeach:
    """The point particle taught by drawing: samples are ``(x, y)`` in the workspace ``[0, 10]^2``,
    environments the 6-D ``(start_x, start_y, wall_x, hole_y, goal_x, goal_y)``.

    Args:
        task: the task (default :class:`~protorch.tasks.PointParticleTask` with its defaults);
            a ``fixed_start`` task is refused (the files hold 6-D environments).
        tol: how far the first (last) sample may lie from the start (goal). The authors' 90 mouse
            demonstrations start at most 0.15 and end at most 0.21 from their targets.
        min_samples: fewer recorded samples is "too short" (the page records about 20 a second).
    """

    name, kind, unit = PointParticleTask.name, "particle", ""
    default_envs = 30  # environments the page proposes
    fmt: DemoFormat = PARTICLE_FORMAT

    def __init__(
        self, task: PointParticleTask | None = None, *, tol: float = 0.3, min_samples: int = 10
    ) -> None:
        self.task = PointParticleTask() if task is None else task
        if self.task.fixed_start is not None:
            raise ValueError(
                "teaching writes 6-D environments: use a point_particle task without fixed_start"
            )
        if not tol > 0 or int(min_samples) < 2:
            raise ValueError(
                f"need tol > 0 and min_samples >= 2, got tol={tol}, min_samples={min_samples}"
            )
        self.tol, self.min_samples = float(tol), int(min_samples)

    def sample_envs(self, n: int, generator: torch.Generator) -> Tensor:
        """``n`` random environments ``(n, 6)`` (the authors' sampler)."""
        return self.task.sample_envs(n, generator)

    def clip(self, point) -> Tensor:
        """A recorded sample ``(2,)``: the pointer's ``(x, y)`` clipped into the workspace."""
        return torch.as_tensor(point, dtype=torch.float64)[:2].clamp(0.0, 10.0)

    def path(self, traj: Tensor) -> np.ndarray:
        """What is drawn of ``traj (T, 2)``: ``(T, 3)`` in the plane ``z = 0``."""
        t = torch.as_tensor(traj, dtype=torch.float64)
        return torch.cat([t, torch.zeros_like(t[:, :1])], 1).numpy()

    def quality(self, raw: Tensor, traj: Tensor, env: Tensor, **_) -> Quality:
        """Checks of a drawing ``raw (n, 2)`` resampled to ``traj (T, 2)`` in ``env (6,)``:
        start and end within ``tol``, at least ``min_samples`` samples, and neither the drawn
        polyline nor the resampled one entering the wall (exact segment test)."""
        q = Quality()
        _common_checks(
            q,
            raw.shape[0],
            float((traj[0] - env[0:2]).norm()),
            float((traj[-1] - env[4:6]).norm()),
            self.tol,
            self.min_samples,
            self.unit,
        )
        clear = float(self.task.clearance(traj, env))
        q.values["clearance"] = clear
        if bool(self.task.collides(raw, env)) or bool(self.task.collides(traj, env)):
            q.fail("collides", f"enters the wall (clearance {clear:.3g})")
        return q


class HandFollower:
    """The arm's joints following a dragged hand target by inverse kinematics (module docstring).
    :meth:`move` returns the configuration and the remaining position error of the hand."""

    def __init__(self, task: ArmReachTask, *, iters: int = 30) -> None:
        self.task, self.iters = task, int(iters)
        kin = task.kinematics
        self.rest = task.start_config(kin.lower.dtype, kin.lower.device)  # (J,)
        self.rotation = kin.ee_pose(self.rest)[:3, :3][None]  # (1, 3, 3) the hand pointing down
        self.reset()

    def reset(self, q: Tensor | None = None) -> None:
        """Back to the start configuration (or ``q (J,)``)."""
        self.q = (self.rest if q is None else torch.as_tensor(q).to(self.rest)).clone()  # (J,)

    def move(self, target) -> tuple[Tensor, float]:
        """``q (J,)`` with the hand at ``target (3,)`` (as near as the arm reaches), pointing down,
        from the current configuration; and the hand's position error (m)."""
        kin = self.task.kinematics
        p = torch.as_tensor(np.asarray(target, dtype=np.float64)).to(self.rest)[None]  # (1, 3)
        q, _ = kin.inverse(
            p, self.q[None], rotation=self.rotation, rest=self.rest, iters=self.iters
        )
        self.q = q[0]
        err = float((kin.ee_position(self.q) - p[0]).norm())
        return self.q.clone(), err

    @property
    def hand(self) -> np.ndarray:
        """The hand's position ``(3,)`` at the current configuration."""
        return self.task.kinematics.ee_position(self.q).cpu().numpy()


class ArmTeach:
    """The arm taught by dragging its hand: samples are the 7 joint angles, environments
    ``(can_x, can_y, goal_x, goal_y)``.

    Args:
        task: the task (default :class:`~protorch.tasks.ArmReachTask`).
        tol: how far the hand may start (end) from the start (target), metres.
        min_samples: fewer recorded configurations is "too short".
        ik_tol: a hand that stayed further than this from the dragged target (the arm could not
            follow: out of reach, joint limits) is flagged.
    """

    name, kind, unit = ArmReachTask.name, "arm", " m"
    default_envs = 20  # environments the page proposes

    def __init__(
        self,
        task: ArmReachTask | None = None,
        *,
        tol: float = 0.03,
        min_samples: int = 10,
        ik_tol: float = 0.01,
    ) -> None:
        self.task = ArmReachTask() if task is None else task
        if not (tol > 0 and ik_tol > 0) or int(min_samples) < 2:
            raise ValueError(
                f"need tol > 0, ik_tol > 0, min_samples >= 2, got {tol}, {ik_tol}, {min_samples}"
            )
        self.tol, self.min_samples, self.ik_tol = float(tol), int(min_samples), float(ik_tol)
        self.fmt = arm_demo_format(self.task)

    def sample_envs(self, n: int, generator: torch.Generator) -> Tensor:
        """``n`` random environments ``(n, 4)`` (the task's sampler and region)."""
        return self.task.sample_envs(n, generator)

    def path(self, traj: Tensor) -> np.ndarray:
        """The hand's path of the joint trajectory ``traj (T, 7)``: ``(T, 3)``."""
        kin = self.task.kinematics
        return self.task.ee_path(torch.as_tensor(traj).to(kin.lower)).cpu().numpy()

    def quality(
        self, raw: Tensor, traj: Tensor, env: Tensor, *, ik_error: float = 0.0, sides: tuple = ()
    ) -> Quality:
        """Checks of the recorded ``raw (n, 7)`` resampled to ``traj (T, 7)`` in ``env (4,)``:
        the hand starts (ends) within ``tol`` of the start (target), at least ``min_samples``
        samples, no part of the arm within the can's radius plus ``margin`` of its axis, no frame
        below the table, the hand followed the target within ``ik_tol`` (``ik_error``, the
        largest miss while recording), and it passes the can on the side of this environment's
        kept demonstrations (``sides``: their labels), so each side gets its own
        demonstrations."""
        task, kin = self.task, self.task.kinematics
        traj, env = traj.to(kin.lower), env.to(kin.lower)
        ee = task.ee_path(traj)  # (T, 3)
        q = Quality()
        _common_checks(
            q,
            raw.shape[0],
            float((ee[0] - task.start_position(ee.dtype, ee.device)).norm()),
            float((ee[-1] - task.goal_point(env)).norm()),
            self.tol,
            self.min_samples,
            self.unit,
        )
        dist = float(task.can_distance(traj, env))
        side = int(task.side(traj, env))
        links = kin.link_positions(traj)  # (T, F, 3)
        q.values.update(can_distance=dist, ik_error=float(ik_error), side=SIDES[side], label=side)
        if dist <= task.can_radius + task.margin:
            q.fail(
                "collides",
                f"the arm comes {dist:.3g} m from the can's axis (radius + margin "
                f"{task.can_radius + task.margin:.3g} m)",
            )
        if not bool((links[:, 1:, 2] >= 0).all()):
            q.fail("table", "part of the arm goes below the table")
        if ik_error > self.ik_tol:
            q.fail(
                "ik", f"the hand could not follow the target (missed it by up to {ik_error:.3g} m)"
            )
        if sides and any(int(s) != side for s in sides):
            q.fail(
                "side",
                f"passes the can on the {SIDES[side]}; this environment's other demonstrations "
                "pass "
                f"on the {SIDES[int(sides[0])]}",
            )
        return q


def make_teach_task(name: str, task=None, **options):
    """The teach task of the task named ``name``: :class:`ParticleTeach` or :class:`ArmTeach`."""
    if name not in TEACH:
        raise ValueError(f"--teach takes one of {', '.join(TEACH_TASKS)}, got {name!r}")
    return TEACH[name](task, **options)


# the teach task of each task name (the task classes' own ``name``)
TEACH: dict[str, type] = {t.name: t for t in (ParticleTeach, ArmTeach)}
TEACH_TASKS = tuple(TEACH)
