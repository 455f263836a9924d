"""How close the arm comes to the can and to the table, under the task's collision model
(:class:`~protorch.tasks.ArmReachTask`'s ``collision``).

* ``"skeleton"``: the segments between consecutive frame origins (base to tool centre point),
  zero thickness. The gap to the can is the segments' distance to the can's axis segment minus
  the can's radius; above the table means every frame but the base at ``z >= 0``.
* ``"volume"``: the robot's link capsules (:attr:`~protorch.robots.Robot.capsules`, the same
  volumes the MuJoCo scene collides with). A capsule's gap to the can is its segment's
  smallest signed distance to the can's solid cylinder, flat top included
  (:func:`~protorch.tasks.arm.geometry.segment_cylinder_distance`), minus the capsule's radius:
  the exact distance between the two bodies, negative when they overlap. Above the table means the lowest
  point of every capsule not on a base link (:attr:`~protorch.robots.Robot.base_links`)
  at ``z >= 0``.

The task's success asks ``gap > margin`` at every step; the moving test places a moved can only
where ``gap > place_clearance``.

The task's can objective (``can_objective``) reads the end effector's distance to the can's axis
(``"ee"``, the paper's), the smallest distance of the skeleton's segments to the can's axis
segment (``"skeleton"``: what the skeleton success check reads, its origins placed by
:meth:`~protorch.robots.ArmKinematics.skeleton`) or, with ``"volume"``, the distance between the can's axis segment and the
surfaces of the capsules that come near the can: those rigid with the end link (the hand with its
fingers, the last link), which pass beside it, and the robot's forearm's
(:attr:`~protorch.robots.Robot.forearm_link`, the Panda's link 5), which passes over it when the
hand passes beside (:func:`end_capsules`, :func:`end_volume_near`). They are placed by the compiled
kinematics (:meth:`~protorch.robots.ArmKinematics.ee_frame`,
:meth:`~protorch.robots.ArmKinematics.frame_points`: about six times the end effector's cost,
where the full chain would be a hundred) so the objectives stay affordable in the loop; each
capsule's distance is taken at its point horizontally nearest the can's axis (horizontal distance
and height above the can's top combined: exact below the top, a cheap stand-in above it).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ...robots import capsule_index, capsule_segments
from .geometry import segment_axis_distance, segment_cylinder_distance

__all__ = ["COLLISIONS", "CAN_OBJECTIVES", "check_collision", "check_volumes", "frames_gap", "capsules_gap",
           "above_table", "end_capsules", "end_volume_near"]

COLLISIONS = ("skeleton", "volume")
CAN_OBJECTIVES = ("ee", "volume", "skeleton")


def check_collision(collision: str, name: str = "collision") -> str:
    """``collision`` if it is one of :data:`COLLISIONS`, else a ``ValueError`` naming the setting."""
    if collision not in COLLISIONS:
        raise ValueError(f"{name} must be one of {', '.join(COLLISIONS)}, got {collision!r}")
    return collision


def check_volumes(robot, frame_names) -> None:
    """Refuse a robot without capsules, or whose capsules ride on links the chain lacks (a clear
    error, before any work)."""
    if not robot.capsule_list():
        raise ValueError(f"collision=volume needs the robot's capsules: {robot.name} has none "
                         "(robot.capsules: auto, or given per link)")
    try:
        capsule_index(frame_names, robot.capsule_list())
    except ValueError as exc:
        raise ValueError(f"collision=volume needs the robot's capsules on its chain: {exc}") from None


def frames_gap(task, frames: Tensor, env: Tensor) -> Tensor:
    """Smallest distance between the arm's surface (under ``task.collision``) and the can's, over
    the steps and the arm's parts: ``frames (..., T, F, 4, 4)`` (e.g.
    :meth:`~protorch.robots.ArmKinematics.frames` of ``(..., T, J)`` joints) and ``env (..., 4)``
    -> ``(...)``; negative when they overlap."""
    if task.collision == "skeleton":
        return task.skeleton_distance(frames[..., :3, 3], env) - task.can_radius
    a, b, r = capsule_segments(frames, task.kinematics.frame_names, task.robot.capsule_list())  # (..., T, C, 3), (C,)
    return capsules_gap(a, b, r, env, task.can_radius, task.can_height)


# the bounds of capsules_gap hold to round-off and the golden-section search's tolerance: a margin
# far above both (1 mm; float32 round-off at the arm's scale is ~1e-7 m) keeps every capsule
# whose exact distance may be the smallest
PRUNE_SLACK = 1e-3


def capsules_gap(a: Tensor, b: Tensor, r: Tensor, env: Tensor, radius: float, height: float) -> Tensor:
    """Smallest signed distance between capsules ``a -> b`` of radius ``r`` (``(..., T, C, 3)``,
    ``(C,)``) and the can of ``env (..., 4)`` (a solid cylinder of ``radius`` from 0 to ``height``):
    ``(...)``, the same numbers as evaluating
    :func:`~protorch.tasks.arm.geometry.segment_cylinder_distance` on every capsule and step.

    Only the capsules that can hold the minimum are searched: a segment's distance to the can's
    axis segment (exact, closed form) bounds its distance to the solid cylinder from above, and
    that minus the can's radius from below (the cylinder lies between the axis segment and the axis
    segment grown by the radius), so a capsule whose lower bound exceeds the smallest upper bound
    (plus :data:`PRUNE_SLACK`) cannot be the nearest; the exact search (elementwise, so each
    capsule's number is the one the full evaluation gives) runs on the rest, typically a few
    percent of them."""
    axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    upper = segment_axis_distance(a, b, axis, 0.0, height) - r  # (..., T, C) >= the exact gap
    if not bool(torch.isfinite(upper).all()):  # NaN in: the full evaluation (which propagates it)
        return (segment_cylinder_distance(a, b, axis, radius, 0.0, height) - r).flatten(-2).amin(-1)
    best = upper.flatten(-2).amin(-1)  # (...)
    idx = torch.nonzero(upper - radius <= best[..., None, None] + PRUNE_SLACK, as_tuple=True)  # the candidates
    shape = upper.shape
    near = segment_cylinder_distance(a.expand(*shape, 3)[idx], b.expand(*shape, 3)[idx],
                                     axis.expand(*shape, 2)[idx], radius, 0.0, height)  # (n,)
    gap = torch.full_like(upper, float("inf"))
    gap[idx] = near - r.expand(shape)[idx]
    return gap.flatten(-2).amin(-1)


def above_table(task, frames: Tensor) -> Tensor:
    """Whether the arm (under ``task.collision``) stays above the table top ``z = 0`` at every
    step: ``frames (..., T, F, 4, 4) -> (...)`` bool."""
    if task.collision == "skeleton":
        return (frames[..., 1:, 2, 3] >= 0).flatten(-2).all(-1)
    capsules = task.robot.capsule_list()
    moving = torch.tensor([c.link not in task.robot.base_links for c in capsules], device=frames.device)
    a, b, r = capsule_segments(frames, task.kinematics.frame_names, capsules)  # (..., T, C, 3)
    low = torch.minimum(a[..., 2], b[..., 2]) - r  # (..., T, C)
    return (low[..., moving] >= 0).flatten(-2).all(-1)


def end_capsules(kinematics, robot) -> dict:
    """The capsules the volume objective reads (module docstring), as ``{frame: (a (C, 3), b (C, 3),
    radius (C,))}`` float64: those on links rigidly attached to the end link, in the end link's
    frame (under the key ``None``), and those of the robot's forearm link (if it has one) in its own."""
    names = kinematics.frame_names
    fixed = [names[-1]]
    for i in range(len(names) - 1, 0, -1):  # back from the end link until the last revolute joint
        if kinematics.chain.find_frame(names[i]).joint.joint_type != "fixed":
            fixed.append(names[i])
            break
        fixed.append(names[i - 1])
    frames = kinematics.frames(torch.zeros(kinematics.num_joints, dtype=torch.float64,
                                           device=kinematics.lower.device)).cpu()  # (F, 4, 4)
    rel = torch.linalg.inv(frames[-1]) @ frames  # (F, 4, 4) every frame in the end link's
    capsules = robot.capsule_list()
    out = {None: capsule_segments(rel, names, [c for c in capsules if c.link in fixed])}
    forearm = [c for c in capsules if c.link == robot.forearm_link]
    if forearm:
        eye = torch.eye(4, dtype=torch.float64).expand(len(names), 4, 4)
        out[robot.forearm_link] = capsule_segments(eye, names, forearm)
    return out


def end_volume_near(kinematics, traj: Tensor, env: Tensor, capsules: dict, can_height: float) -> Tensor:
    """At every other step, the smallest distance between the can's axis segment and the surfaces
    of the objective's capsules (:func:`end_capsules`): ``traj (..., T, J)``, ``env (..., 4)`` ->
    ``(..., ceil(T / 2))``; the can's radius is not subtracted, so it reads like the end
    effector's distance to the axis. Also returns the end link's positions at every step ``(..., T, 3)``."""
    axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    full, traj = traj, traj[..., ::2, :]  # every other step: the shaping term's cost halved
    coarse = kinematics.ee_frame(traj)  # (..., T', 4, 4) the end link's pose where the capsules are read
    path = torch.empty(*full.shape[:-1], 3, dtype=full.dtype, device=full.device)  # (..., T, 3)
    path[..., ::2, :] = coarse[..., :3, 3]  # ee_frame's origin is ee_position's, to the bit
    path[..., 1::2, :] = kinematics.ee_position(full[..., 1::2, :])
    near = []
    for frame, (a, b, r) in capsules.items():
        a, b, r = a.to(traj), b.to(traj), r.to(traj)
        if frame is None:  # the ends in the end link's frame, all placed by one matrix product
            ends = torch.cat([a, b])  # (2C, 3)
            ends = torch.cat([ends, torch.ones_like(ends[:, :1])], 1)  # (2C, 4) homogeneous
            placed = (coarse[..., :3, :].reshape(-1, 4) @ ends.T).unflatten(0, (*coarse.shape[:-2], 3))  # (..., T', 3, 2C)
            placed = placed.transpose(-1, -2)  # (..., T', 2C, 3)
            pa, pb = placed[..., : a.shape[0], :].contiguous(), placed[..., a.shape[0]:, :].contiguous()  # (..., T', C, 3)
        else:
            ends = kinematics.frame_points(traj, frame, torch.cat([a, b]))  # (..., T, 2C, 3)
            pa, pb = ends[..., : a.shape[0], :], ends[..., a.shape[0]:, :]
        near.append(_axis_proxy(pa, pb, axis, can_height) - r)  # (..., T, C)
    return torch.cat(near, -1).amin(-1), path


def _axis_proxy(pa: Tensor, pb: Tensor, axis: Tensor, height: float) -> Tensor:
    """A cheap stand-in for the distance of segments ``pa -> pb`` to the can's axis segment: at the
    segment's point horizontally nearest the axis, the horizontal distance and the height above the
    can's top, combined (exact for a segment below the top or level; the objective's shaping only)."""
    d = pb - pa  # (..., 3)
    w = axis - pa[..., :2]  # (..., 2)
    u = ((w * d[..., :2]).sum(-1) / d[..., :2].square().sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)  # (...)
    h = (w - u[..., None] * d[..., :2]).norm(dim=-1)
    v = (pa[..., 2] + u * d[..., 2] - height).clamp(min=0.0)
    return torch.sqrt(h.square() + v.square())
