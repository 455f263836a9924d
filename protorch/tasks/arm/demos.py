"""The arm-reach task's demonstrator (:meth:`protorch.tasks.ArmReachTask.demonstrations`):
end-effector paths around the can, followed in joint space by inverse kinematics."""

from __future__ import annotations

import torch
from torch import Tensor

from ...checks import check_tensor
from ...data.demos import DemoFolder, DemoFormat, read_demo_folder
from ..curves import catmull_rom, smooth_noise
from .geometry import LEFT, RIGHT

__all__ = [
    "arm_demo_format",
    "beside_can",
    "detour_paths",
    "follow_path",
    "ik_demonstrations",
    "read_arm_demos",
    "straight_paths",
]


def arm_demo_format(task) -> DemoFormat:
    """The arm's demonstration files (:mod:`protorch.data.demos`): ``trajK.out`` one row of the
    7 joint angles (radians, the URDF's joint order) per sample, each inside its joint limits;
    ``envK.out`` the 4 numbers ``can_x can_y goal_x goal_y`` (metres), each on the table."""
    kin = task.kinematics
    (x0, x1), (y0, y1) = task.table
    return DemoFormat(
        tuple(kin.joint_names),
        tuple(task.env_names),
        tuple(zip(kin.lower.tolist(), kin.upper.tolist())),
        ((x0, x1), (y0, y1)) * 2,
        "the joint limits",
        "the table",
    )


def read_arm_demos(task, folder, cleaning=None) -> tuple[DemoFolder, Tensor]:
    """A folder of arm demonstrations, either format (:func:`~protorch.data.demos.read_demo_folder`:
    timestamped ``*.csv`` recordings cleaned by ``cleaning``, a
    :class:`~protorch.data.recordings.Cleaning`, or ``trajK.out`` / ``envK.out``;
    :func:`arm_demo_format`, errors naming file and line) and the homotopy class of each
    demonstration (:meth:`~protorch.tasks.ArmReachTask.side`, measured on its joint trajectory
    and its own environment): ``(folder, labels (n,))``."""
    dev = task.kinematics.lower.device
    side = lambda d, e: task.side(d.to(dev), e.to(dev)).cpu()
    demos, labels = read_demo_folder(folder, arm_demo_format(task), cleaning, labeller=side)
    if labels is None:
        labels = torch.stack([side(d, e) for d, e in zip(demos.demos, demos.envs)]).reshape(-1)
    return demos, labels  # (n,)


def follow_path(
    task, path: Tensor, *, iters: int = 8, first_iters: int = 60, compiled: bool = False
) -> tuple[Tensor, Tensor]:
    """:meth:`~protorch.tasks.ArmReachTask.ik_path` of ``task``: joint trajectories following the
    end-effector paths ``(n, T, 3)``; ``(q (n, T, 7), position error (n, T))``. ``compiled``: the
    compiled chain's Jacobian (:meth:`~protorch.robots.ArmKinematics.jacobian_pose`)."""
    path = check_tensor(path, "path", ndim=3)
    kin = task.kinematics
    dtype, device = kin.lower.dtype, kin.lower.device
    path = path.to(dtype=dtype, device=device)
    n, t_len = path.shape[:2]
    rest = task.start_config(dtype, device)
    rot = kin.ee_pose(rest)[:3, :3].expand(
        n, 3, 3
    )  # the hand keeps its start orientation (pointing down)
    q = rest.expand(n, -1).clone()  # (n, J)
    out = torch.empty(n, t_len, kin.num_joints, dtype=dtype, device=device)
    err = torch.empty(n, t_len, dtype=dtype, device=device)
    for t in range(t_len):
        q, err[:, t] = kin.inverse(
            path[:, t],
            q,
            rotation=rot,
            rest=rest,
            iters=first_iters if t == 0 else iters,
            compiled=compiled,
        )
        out[:, t] = q
    return out, err


def straight_paths(task, env: Tensor, num_steps: int = 100) -> Tensor:
    """The straight end-effector path from the task's start to the target of each environment
    ``env (n, 4)``, with a minimum-jerk time profile: ``(n, num_steps, 3)``."""
    u = torch.linspace(0, 1, int(num_steps), dtype=torch.float64)
    prog = u**3 * (10 - 15 * u + 6 * u**2)  # (T,)
    s = task.start_position()
    g = task.goal_point(env.reshape(-1, 4))  # (n, 3)
    return s + prog[None, :, None] * (g - s)[:, None, :]  # (n, T, 3)


def beside_can(task, env: Tensor, side: Tensor, distance: Tensor) -> Tensor:
    """Points ``distance (n, 1)`` beside the can of each environment ``env (n, 4)`` on ``side (n,)``
    (:data:`LEFT` or :data:`RIGHT` of the line from the start to the target, perpendicular to
    it): ``(n, 2)``."""
    line = task.goal_point(env)[:, :2] - task.start_position()[:2]  # (n, 2)
    line = line / line.norm(dim=-1, keepdim=True)
    normal = torch.stack([-line[:, 1], line[:, 0]], -1)  # (n, 2) to the left of the line
    sign = torch.where(side == LEFT, 1.0, -1.0).to(env.dtype)[:, None]  # (n, 1)
    return env[:, :2] + sign * distance * normal


def detour_paths(
    task, env: Tensor, side: Tensor | int, distance: float, num_steps: int = 100
) -> Tensor:
    """The demonstrator's path without its noise: from the start through the point ``distance``
    beside the can on ``side`` (:func:`beside_can`, at the target's height) to the target of each
    environment ``env (n, 4)``, a Catmull-Rom curve with a minimum-jerk time profile:
    ``(n, num_steps, 3)``. The arm's detour priors (``task.prior_detours``)."""
    env = env.reshape(-1, 4).to(torch.float64)
    n = env.shape[0]
    side = torch.as_tensor(side).long().expand(n)
    if not float(distance) > 0:
        raise ValueError(f"a detour's distance must be > 0, got {distance}")
    s, goal = task.start_position(), task.goal_point(env)  # (3,), (n, 3)
    beside = beside_can(task, env, side, torch.full((n, 1), float(distance), dtype=torch.float64))
    via = torch.stack([s.expand(n, 3), torch.cat([beside, goal[:, 2:]], -1), goal], 1)  # (n, 3, 3)
    u = torch.linspace(0, 1, int(num_steps), dtype=torch.float64)
    prog = u**3 * (10 - 15 * u + 6 * u**2)  # (T,)
    return catmull_rom(via, prog.expand(n, -1))  # (n, T, 3)


def ik_demonstrations(
    task,
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
    """:meth:`~protorch.tasks.ArmReachTask.demonstrations` of ``task`` (documented there):
    ``(demos [(T_i, 7)], demo_envs (n, 4), labels (n,))``."""
    if isinstance(envs, int):
        envs = task.sample_envs(envs, generator)
    envs = task.check_envs(check_tensor(envs, "envs", ndim=2)).to(torch.float64)
    if int(per_env) < 1:
        raise ValueError(f"per_env must be >= 1, got {per_env}")
    m = envs.shape[0]
    sides = torch.arange(m) % 2 if sides is None else torch.as_tensor(sides).long().reshape(-1)
    if sides.shape[0] != m or not bool(((sides == LEFT) | (sides == RIGHT)).all()):
        raise ValueError(f"sides must hold {m} entries of {LEFT} (left) or {RIGHT} (right)")
    t_min, t_max = int(lengths[0]), int(lengths[1])
    if not 2 <= t_min <= t_max:
        raise ValueError(f"lengths must be (lo, hi) with 2 <= lo <= hi, got {lengths}")
    g_, f64 = generator, torch.float64
    e = envs.repeat_interleave(int(per_env), 0)  # (n, 4)
    side = sides.repeat_interleave(int(per_env))  # (n,)
    n = e.shape[0]
    s = task.start_position()  # (3,)
    goal = task.goal_point(e)  # (n, 3)
    dist = pass_distance[0] + (pass_distance[1] - pass_distance[0]) * torch.rand(
        n, 1, generator=g_, dtype=f64
    )
    beside = beside_can(task, e, side, dist)  # (n, 2) beside the can, perpendicular to the line
    lift = 0.03 * torch.rand(n, 1, generator=g_, dtype=f64)  # (n, 1)
    h = task.ee_height
    end = goal + torch.cat(
        [goal_noise * torch.randn(n, 2, generator=g_, dtype=f64), torch.zeros(n, 1, dtype=f64)], -1
    )
    via = torch.stack([s.expand(n, 3), torch.cat([beside, h + lift], -1), end], 1)  # (n, 3, 3)
    length = torch.randint(t_min, t_max + 1, (n, 1), generator=g_)  # (n, 1)
    skew = 0.8 + 0.45 * torch.rand(n, 1, generator=g_, dtype=f64)  # (n, 1)
    u = (torch.arange(t_max, dtype=f64) / (length - 1)).clamp(max=1)  # (n, T_max)
    v = u**skew
    prog = v**3 * (10 - 15 * v + 6 * v**2)  # (n, T_max) minimum-jerk progress along the path
    path = catmull_rom(via, prog)  # (n, T_max, 3)
    wobble = (
        smooth_noise(u, tremor, g_, dim=3) * torch.sin(torch.pi * prog)[..., None]
    )  # (n, T_max, 3)
    path = path + wobble
    q, _ = task.ik_path(path)  # (n, T_max, 7)
    q = q.to(torch.float64).cpu()
    demos = [qi[:t].clone() for qi, t in zip(q, length[:, 0].tolist())]
    labels = torch.stack([task.side(d, ei) for d, ei in zip(demos, e)])  # (n,)
    return demos, e, labels
