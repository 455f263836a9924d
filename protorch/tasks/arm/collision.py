"""How close the arm comes to the can and to the table, under the task's collision model
(:class:`~protorch.tasks.ArmReachTask`'s ``collision``).

* ``"skeleton"``: the segments between consecutive frame origins (base to tool centre point),
  zero thickness. The gap to the can is the segments' distance to the can's axis segment minus
  the can's radius; above the table means every frame but the base at ``z >= 0``.
* ``"volume"``: the robot's link capsules (:attr:`~protorch.robots.Robot.capsules`, the same
  volumes the MuJoCo scene collides with). A capsule's gap to the can is its segment's
  smallest signed distance to the can's solid cylinder, flat top included
  (:func:`~protorch.tasks.arm.geometry.segment_cylinder_distance`), minus the capsule's radius:
  the exact distance between the two bodies, negative when they overlap. Above the table means the
  lowest
  point of every capsule not on a base link (:attr:`~protorch.robots.Robot.base_links`)
  at ``z >= 0``.

The task's success asks ``gap > margin`` at every step; the moving test places a moved can only
where ``gap > place_clearance``.

The task's can objective (``can_objective``) reads the end effector's distance to the can's axis
(``"ee"``, the paper's), the smallest distance of the skeleton's segments to the can's axis
segment (``"skeleton"``: what the skeleton success check reads, its origins placed by
:meth:`~protorch.robots.ArmKinematics.skeleton`) or, with ``"volume"``, the distance between the
can's axis segment and the
surfaces of the capsules that come near the can: those rigid with the end link (the hand with its
fingers, the last link), which pass beside it, and the robot's forearm's
(:attr:`~protorch.robots.Robot.forearm_link`, the Panda's link 5), which passes over it when the
hand passes beside (:func:`end_capsules`, :func:`end_volume_near`). They are placed by the compiled
kinematics (:meth:`~protorch.robots.ArmKinematics.ee_frame`,
:meth:`~protorch.robots.ArmKinematics.carry_points`: about six times the end effector's cost,
where the full chain would be a hundred) so the objectives stay affordable in the loop; each
capsule's distance is taken at its point horizontally nearest the can's axis (horizontal distance
and height above the can's top combined: exact below the top, a cheap stand-in above it).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ...robots import PointPlan, capsule_index, capsule_segments
from ...threads import one_thread
from .geometry import (
    broadcast_shape,
    point_cylinder_distance,
    segment_axis_closest,
    segment_axis_distance,
    segment_cylinder_distance,
    segment_cylinder_within,
)

__all__ = [
    "COLLISIONS",
    "CAN_OBJECTIVES",
    "check_collision",
    "check_volumes",
    "frames_gap",
    "capsules_gap",
    "capsules_clear",
    "above_table",
    "end_capsules",
    "end_volume_near",
    "capsule_plan",
    "capsule_ends",
    "capsules_above_table",
    "joints_clearance",
]

COLLISIONS = ("skeleton", "volume")
CAN_OBJECTIVES = ("ee", "volume", "skeleton")


def check_collision(collision: str, name: str = "collision") -> str:
    """``collision`` if it is one of :data:`COLLISIONS`, else a ``ValueError`` naming
    the setting."""
    if collision not in COLLISIONS:
        raise ValueError(f"{name} must be one of {', '.join(COLLISIONS)}, got {collision!r}")
    return collision


def check_volumes(robot, frame_names) -> None:
    """Refuse a robot without capsules, or whose capsules ride on links the chain lacks (a clear
    error, before any work)."""
    if not robot.capsule_list():
        raise ValueError(
            f"collision=volume needs the robot's capsules: {robot.name} has none "
            "(robot.capsules: auto, or given per link)"
        )
    try:
        capsule_index(frame_names, robot.capsule_list())
    except ValueError as exc:
        raise ValueError(
            f"collision=volume needs the robot's capsules on its chain: {exc}"
        ) from None


def frames_gap(task, frames: Tensor, env: Tensor) -> Tensor:
    """Smallest distance between the arm's surface (under ``task.collision``) and the can's, over
    the steps and the arm's parts: ``frames (..., T, F, 4, 4)`` (e.g.
    :meth:`~protorch.robots.ArmKinematics.frames` of ``(..., T, J)`` joints) and ``env (..., 4)``
    -> ``(...)``; negative when they overlap."""
    if task.collision == "skeleton":
        return task.skeleton_distance(frames[..., :3, 3], env) - task.can_radius
    a, b, r = capsule_segments(
        frames, task.kinematics.frame_names, task.robot.capsule_list()
    )  # (..., T, C, 3), (C,)
    return capsules_gap(a, b, r, env, task.can_radius, task.can_height)


def capsule_plan(kinematics, capsules) -> PointPlan:
    """The capsules' end points (``a`` of every capsule, then ``b``) prepared for
    :meth:`~protorch.robots.ArmKinematics.carry_points`."""
    links = [c.link for c in capsules]
    pts = torch.tensor(
        [c.a for c in capsules] + [c.b for c in capsules], dtype=torch.float64
    )  # (2C, 3)
    return kinematics.point_plan(links + links, pts)


def capsule_ends(
    kinematics, traj: Tensor, plan: PointPlan, *, functional: bool = False
) -> tuple[Tensor, Tensor]:
    """The capsules of ``plan`` (:func:`capsule_plan`) placed at joints ``traj (..., J)``: ``a``,
    ``b`` ``(..., C, 3)`` in the base frame, by the compiled kinematics (equal to
    :func:`~protorch.robots.capsule_segments` of the chain's frames to round-off, several times
    cheaper); ``functional``: nothing written in place (for ``torch.export``, the same numbers)."""
    ends = kinematics.carry_points(traj, plan, functional=functional)  # (..., 2C, 3)
    c = ends.shape[-2] // 2
    return ends[..., :c, :], ends[..., c:, :]


# the bounds of capsules_gap hold to round-off and the golden-section search's tolerance: a margin
# far above both (1 mm; float32 round-off at the arm's scale is ~1e-7 m) keeps every capsule
# whose exact distance may be the smallest
PRUNE_SLACK = 1e-3


def capsules_gap(
    a: Tensor, b: Tensor, r: Tensor, env: Tensor, radius: float, height: float
) -> Tensor:
    """Smallest signed distance between capsules ``a -> b`` of radius ``r`` (``(..., T, C, 3)``,
    ``(C,)``) and the can of ``env (..., 4)`` (a solid cylinder of ``radius`` from 0 to ``height``):
    ``(...)``, the same numbers as evaluating
    :func:`~protorch.tasks.arm.geometry.segment_cylinder_distance` on every capsule and step.

    Only the capsules that can hold the minimum are searched, in two rounds of bounds. First from
    each segment's midpoint ``m`` and half horizontal length ``l``: the midpoint's distance to the
    cylinder bounds the segment's from above; ``max(|m - axis|_xy - l - radius, -z_max,
    z_min - height)`` from below (every point of the segment is that far outside the cylinder's
    side or its bottom or top plane). Then, for the capsules left, the segment's exact distance to
    the can's axis segment (closed form) bounds its distance to the solid cylinder from above, and
    that minus the can's radius from below (the cylinder lies between the axis segment and the
    axis segment grown by the radius). A capsule whose lower bound exceeds the smallest upper bound
    (plus :data:`PRUNE_SLACK`) cannot be the nearest; the exact search (elementwise, so each
    capsule's number is the one the full evaluation gives) runs on the rest, typically a few
    percent of them."""
    axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    if not (
        bool(torch.isfinite(a).all()) and bool(torch.isfinite(b).all())
    ):  # NaN in: the full evaluation
        return (segment_cylinder_distance(a, b, axis, radius, 0.0, height) - r).flatten(-2).amin(-1)
    m = 0.5 * (a + b)  # (..., T, C, 3)
    half = 0.5 * (b[..., :2] - a[..., :2]).norm(dim=-1)  # (..., T, C)
    za, zb = a[..., 2], b[..., 2]
    lower = (
        torch.maximum(
            (m[..., :2] - axis).norm(dim=-1) - half - radius,
            torch.maximum(-torch.maximum(za, zb), torch.minimum(za, zb) - height),
        )
        - r
    )  # (..., T, C)
    upper = point_cylinder_distance(m, axis, radius, 0.0, height) - r  # (..., T, C)
    shape = upper.shape
    best = upper.flatten(-2).amin(-1)  # (...)
    idx = torch.nonzero(
        lower <= best[..., None, None] + PRUNE_SLACK, as_tuple=True
    )  # the first round's candidates
    a_i, b_i, ax_i, r_i = (
        a.expand(*shape, 3)[idx],
        b.expand(*shape, 3)[idx],
        axis.expand(*shape, 2)[idx],
        r.expand(shape)[idx],
    )  # (n, 3), (n, 3), (n, 2), (n,)
    upper_i = segment_axis_distance(a_i, b_i, ax_i, 0.0, height) - r_i  # (n,) >= the exact gap
    bound = torch.full_like(upper, float("inf"))
    bound[idx] = upper_i
    best = torch.minimum(best, bound.flatten(-2).amin(-1))  # (...)
    keep = upper_i - radius <= best[idx[:-2]] + PRUNE_SLACK  # (n,) the second round's candidates
    near = segment_cylinder_distance(a_i[keep], b_i[keep], ax_i[keep], radius, 0.0, height)  # (n',)
    gap = torch.full_like(upper, float("inf"))
    gap[tuple(i[keep] for i in idx)] = near - r_i[keep]
    return gap.flatten(-2).amin(-1)


def capsules_clear(
    a: Tensor,
    b: Tensor,
    r: Tensor,
    env: Tensor,
    radius: float,
    height: float,
    margin: float | Tensor,
    *,
    with_lower: bool = False,
) -> Tensor | tuple[Tensor, Tensor]:
    """Whether :func:`capsules_gap` ``> margin``: ``(...)`` bool, the same verdict at a fraction
    of the cost (a gap within the search's tolerance, about 1e-9 m, of ``margin`` aside).
    ``margin``: one number, or a tensor broadcastable to ``(...)`` (one margin per batch entry).

    Bounds of each capsule's gap in closed form: from below, its segment's distance ``d`` to the
    can's axis segment minus the can's radius (the cylinder lies within that distance of its
    axis); from above, the can's distance at the segment's point closest to the axis. Where that
    point is level with the can's side both are the same number (the exact gap). The
    golden-section search (:func:`~protorch.tasks.arm.geometry.segment_cylinder_within`, each
    capsule stopped once decided) runs only on capsules whose bounds straddle ``margin`` (the
    segment nearest the can's rim or top) in batch entries no bound has decided. ``with_lower``:
    also the smallest of the capsules' lower bounds at each step ``(..., T)`` (what
    :class:`~protorch.control.plan_memo.ClearanceMemo` keeps)."""
    axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    shape = broadcast_shape(a.shape[:-1], axis.shape[:-1])  # (..., T, C)
    d, u = segment_axis_closest(a, b, axis, 0.0, height)  # (..., T, C)
    lower = d - radius - r  # (..., T, C) <= the exact gap
    upper = (
        point_cylinder_distance(a + u[..., None] * (b - a), axis, radius, 0.0, height) - r
    )  # >= the exact gap
    # bounds in closed form hold to round-off: within a few ulps of margin they decide nothing
    slack = 64 * torch.finfo(a.dtype).eps
    m = margin[..., None, None] if isinstance(margin, Tensor) else margin  # (..., 1, 1) | a number
    hit = (upper <= m - slack).flatten(-2).any(-1)  # (...) a capsule surely within margin
    unsure = (lower <= m + slack) & (upper > m - slack) & ~hit[..., None, None]  # (..., T, C)
    clear = ~hit
    if bool(unsure.any()):
        idx = torch.nonzero(unsure, as_tuple=True)
        a_i, b_i, ax_i = (
            a.expand(*shape, 3)[idx],
            b.expand(*shape, 3)[idx],
            axis.expand(*shape, 2)[idx],
        )
        m_i = m.expand(shape)[idx] if isinstance(m, Tensor) else m  # (n,) | a number
        within = torch.zeros(shape, dtype=torch.bool, device=a.device)
        within[idx] = segment_cylinder_within(
            a_i, b_i, ax_i, radius, 0.0, height, r.expand(shape)[idx], m_i
        )
        clear = clear & ~within.flatten(-2).any(-1)
    return (clear, lower.amin(-1)) if with_lower else clear  # (...), (..., T)


def above_table(task, frames: Tensor) -> Tensor:
    """Whether the arm (under ``task.collision``) stays above the table top ``z = 0`` at every
    step: ``frames (..., T, F, 4, 4) -> (...)`` bool."""
    if task.collision == "skeleton":
        return (frames[..., 1:, 2, 3] >= 0).flatten(-2).all(-1)
    a, b, r = capsule_segments(
        frames, task.kinematics.frame_names, task.robot.capsule_list()
    )  # (..., T, C, 3)
    return capsules_above_table(task, a, b, r)


# configurations per piece of joints_clearance: a few MB of capsule ends, held in the cache
CLEARANCE_CHUNK = 1 << 16


def joints_clearance(
    task, traj: Tensor, env: Tensor, chunk: int | None = CLEARANCE_CHUNK
) -> tuple[Tensor, Tensor]:
    """Under the volumes, from joints ``traj (..., T, J)`` and ``env (..., 4)``: the arm-can gap
    (:func:`frames_gap`) and whether the arm stays above the table (:func:`above_table`), both
    ``(...)``, the capsules placed by the compiled kinematics (``task.capsule_plan``).

    Many trajectories (the detour priors' thousands) are taken a piece of about ``chunk``
    configurations at a time (``None``: all in one call), a multiple of 32 trajectories: each
    piece's temporaries stay in the cache and the peak memory is bounded (1.6x faster on 2,000 x
    100 steps, ``benchmarks/arm_volume.py``), and every tensor of a piece but the last fills
    torch's vectorised loops exactly, so the numbers are those of one call
    (``tests/tasks/arm/test_collision.py``)."""
    lead = broadcast_shape(traj.shape[:-2], env.shape[:-1])
    n, steps = lead.numel(), traj.shape[-2]
    per = (
        n if chunk is None else max(32, chunk // max(steps, 1) // 32 * 32)
    )  # trajectories per piece
    if n <= per:
        return _clearance(task, traj, env)
    flat = traj.expand(*lead, *traj.shape[-2:]).reshape(n, *traj.shape[-2:])  # (n, T, J)
    envs = env.expand(*lead, env.shape[-1]).reshape(n, env.shape[-1])  # (n, 4)
    parts = [_clearance(task, flat[i : i + per], envs[i : i + per]) for i in range(0, n, per)]
    return tuple(torch.cat([p[k] for p in parts]).reshape(lead) for k in (0, 1))


def _clearance(task, traj: Tensor, env: Tensor) -> tuple[Tensor, Tensor]:
    a, b = capsule_ends(task.kinematics, traj, task.capsule_plan)  # (..., T, C, 3)
    r = task.capsule_radii.to(a)  # (C,)
    return capsules_gap(a, b, r, env, task.can_radius, task.can_height), capsules_above_table(
        task, a, b, r
    )


def capsules_above_table(task, a: Tensor, b: Tensor, r: Tensor) -> Tensor:
    """:func:`above_table` of placed capsules ``a``, ``b`` ``(..., T, C, 3)`` of radius ``r (C,)``
    (the robot's capsules in :meth:`~protorch.robots.Robot.capsule_list`'s order): ``(...)``."""
    moving = torch.tensor(
        [c.link not in task.robot.base_links for c in task.robot.capsule_list()], device=a.device
    )
    low = torch.minimum(a[..., 2], b[..., 2]) - r  # (..., T, C)
    return (low[..., moving] >= 0).flatten(-2).all(-1)


def end_capsules(kinematics, robot) -> dict:
    """The capsules the volume objective reads (module docstring) as a dict: under the key ``None``
    those on links rigidly attached to the end link, ``(a (C, 3), b (C, 3), radius (C,))`` float64
    in
    the end link's frame; under the robot's forearm link (if it has one) its capsules as
    ``(plan, radius (C,))`` (:func:`capsule_plan`)."""
    names = kinematics.frame_names
    fixed = [names[-1]]
    for i in range(len(names) - 1, 0, -1):  # back from the end link until the last revolute joint
        if kinematics.chain.find_frame(names[i]).joint.joint_type != "fixed":
            fixed.append(names[i])
            break
        fixed.append(names[i - 1])
    frames = kinematics.frames(
        torch.zeros(kinematics.num_joints, dtype=torch.float64, device=kinematics.lower.device)
    ).cpu()  # (F, 4, 4)
    rel = torch.linalg.inv(frames[-1]) @ frames  # (F, 4, 4) every frame in the end link's
    capsules = robot.capsule_list()
    out = {None: capsule_segments(rel, names, [c for c in capsules if c.link in fixed])}
    forearm = [c for c in capsules if c.link == robot.forearm_link]
    if forearm:
        out[robot.forearm_link] = (
            capsule_plan(kinematics, forearm),
            torch.tensor([c.radius for c in forearm], dtype=torch.float64),
        )
    return out


def end_volume_near(
    kinematics, traj: Tensor, env: Tensor, capsules: dict, can_height: float
) -> Tensor:
    """At every other step, the smallest distance between the can's axis segment and the surfaces
    of the objective's capsules (:func:`end_capsules`): ``traj (..., T, J)``, ``env (..., 4)`` ->
    ``(..., ceil(T / 2))``; the can's radius is not subtracted, so it reads like the end
    effector's distance to the axis. Also returns the end link's positions at every step ``(..., T,
    3)``.
    Computed component-major over the flattened batch (rows ``(C, P)``, no transposes)."""
    full, traj = traj, traj[..., ::2, :]  # every other step: the shaping term's cost halved
    lead = traj.shape[:-1]  # (..., T')
    cx, cy = (
        env[..., None, i].expand(lead).reshape(-1) for i in (0, 1)
    )  # (P,) the can's axis at each pose
    path = torch.empty(*full.shape[:-1], 3, dtype=full.dtype, device=full.device)  # (..., T, 3)
    path[..., 1::2, :] = kinematics.ee_position(full[..., 1::2, :])
    trig = kinematics.trig_rows(traj)  # (J, P) cos, sin: once for every frame's capsules
    near = None
    for frame, caps in capsules.items():
        r = caps[-1].to(traj)[:, None]  # (C, 1)
        if (
            frame is None
        ):  # the ends in the end link's frame, all placed by one matrix product per row
            rows = kinematics.ee_frame_rows(
                traj, trig
            )  # x, y, z (4, P): the end link's axes and origin
            path[..., ::2, :] = torch.stack([row[3] for row in rows], -1).reshape(
                *lead, 3
            )  # ee_position's, to the bit
            ends = torch.cat([caps[0], caps[1]]).to(traj)  # (2C, 3)
            ends = torch.cat([ends, torch.ones_like(ends[:, :1])], 1)  # (2C, 4) homogeneous
            with (
                one_thread()
            ):  # MKL splits the P columns between threads: other last bits on two than on one
                x, y, z = (ends @ row for row in rows)  # (2C, P)
        else:
            x, y, z = kinematics.carry_points_rows(traj, caps[0], trig=trig)  # (2C, P)
        c = r.shape[0]
        d = (
            _axis_proxy(x[:c], y[:c], z[:c], x[c:], y[c:], z[c:], cx, cy, can_height)
            .sub_(r)
            .amin(0)
        )  # (P,)
        near = d if near is None else torch.minimum(near, d)
    return near.reshape(lead), path


def _axis_proxy(
    ax: Tensor,
    ay: Tensor,
    az: Tensor,
    bx: Tensor,
    by: Tensor,
    bz: Tensor,
    cx: Tensor,
    cy: Tensor,
    height: float,
) -> Tensor:
    """A cheap stand-in for the distance of segments ``a -> b`` (component rows ``(C, P)``) to the
    can's axis segment over ``(cx, cy)`` (``(P,)``): at the segment's point horizontally nearest
    the axis, the horizontal distance and the height above the can's top, combined (exact for a
    segment below the top or level; the objective's shaping only): ``(C, P)``."""
    dx, dy, dz = bx - ax, by - ay, bz - az  # (C, P)
    wx, wy = cx - ax, cy - ay  # (C, P)
    u = (
        (wx * dx)
        .addcmul_(wy, dy)
        .div_((dx * dx).addcmul_(dy, dy).clamp_min_(1e-12))
        .clamp_(0.0, 1.0)
    )
    hx, hy = wx.addcmul_(u, dx, value=-1.0), wy.addcmul_(u, dy, value=-1.0)
    v = dz.mul_(u).add_(az).sub_(height).clamp_(min=0.0)
    return (hx * hx).addcmul_(hy, hy).addcmul_(v, v).sqrt_()
