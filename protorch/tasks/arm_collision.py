"""How close the arm comes to the can and to the table, under the task's collision model
(:class:`~protorch.tasks.ArmReachTask`'s ``collision``).

* ``"skeleton"``: the segments between consecutive frame origins (base to tool centre point),
  zero thickness. The gap to the can is the segments' distance to the can's axis segment minus
  the can's radius; above the table means every frame but the base at ``z >= 0``.
* ``"volume"``: the Panda's link capsules (:data:`~protorch.robots.panda_volumes.PANDA_CAPSULES`,
  the same volumes the MuJoCo scene collides with). A capsule's gap to the can is its segment's
  smallest signed distance to the can's solid cylinder, flat top included
  (:func:`~protorch.tasks.arm_geometry.segment_cylinder_distance`), minus the capsule's radius:
  the exact distance between the two bodies, negative when they overlap. Above the table means the lowest
  point of every capsule not on a base link (:data:`~protorch.robots.panda_volumes.PANDA_BASE_LINKS`)
  at ``z >= 0``.

The task's success asks ``gap > margin`` at every step; the moving test places a moved can only
where ``gap > place_clearance``.

The task's can objective (``can_objective``) reads the end effector's distance to the can's axis
(``"ee"``, the paper's) or, with ``"volume"``, the horizontal distance between the can's surface
and the capsules rigid with the end link (the hand with its fingers and link 7, the parts that
pass beside the can; :func:`end_capsules`, :func:`end_volume_near`), computed from the end
link's pose by the compiled kinematics (:meth:`~protorch.robots.ArmKinematics.ee_frame`, about
three times the end-effector position's cost) so the objectives stay cheap enough for the loop.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..robots.panda_volumes import PANDA_BASE_LINKS, PANDA_CAPSULES, capsule_index, capsule_segments
from .arm_geometry import segment_cylinder_distance

__all__ = ["COLLISIONS", "CAN_OBJECTIVES", "check_collision", "check_volumes", "frames_gap", "above_table",
           "end_capsules", "end_volume_near"]

COLLISIONS = ("skeleton", "volume")
CAN_OBJECTIVES = ("ee", "volume")


def check_collision(collision: str, name: str = "collision") -> str:
    """``collision`` if it is one of :data:`COLLISIONS`, else a ``ValueError`` naming the setting."""
    if collision not in COLLISIONS:
        raise ValueError(f"{name} must be one of {', '.join(COLLISIONS)}, got {collision!r}")
    return collision


def check_volumes(frame_names) -> None:
    """Refuse an arm whose frames do not carry the Panda's capsules (a clear error, before any work)."""
    try:
        capsule_index(frame_names)
    except ValueError as exc:
        raise ValueError(f"collision=volume needs the Panda's links: {exc}") from None


def frames_gap(task, frames: Tensor, env: Tensor) -> Tensor:
    """Smallest distance between the arm's surface (under ``task.collision``) and the can's, over
    the steps and the arm's parts: ``frames (..., T, F, 4, 4)`` (e.g.
    :meth:`~protorch.robots.ArmKinematics.frames` of ``(..., T, J)`` joints) and ``env (..., 4)``
    -> ``(...)``; negative when they overlap."""
    if task.collision == "skeleton":
        return task.skeleton_distance(frames[..., :3, 3], env) - task.can_radius
    a, b, r = capsule_segments(frames, task.kinematics.frame_names)  # (..., T, C, 3), (C,)
    axis = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    d = segment_cylinder_distance(a, b, axis, task.can_radius, 0.0, task.can_height) - r  # (..., T, C)
    return d.flatten(-2).amin(-1)


def above_table(task, frames: Tensor) -> Tensor:
    """Whether the arm (under ``task.collision``) stays above the table top ``z = 0`` at every
    step: ``frames (..., T, F, 4, 4) -> (...)`` bool."""
    if task.collision == "skeleton":
        return (frames[..., 1:, 2, 3] >= 0).flatten(-2).all(-1)
    moving = torch.tensor([c.link not in PANDA_BASE_LINKS for c in PANDA_CAPSULES], device=frames.device)
    a, b, r = capsule_segments(frames, task.kinematics.frame_names)  # (..., T, C, 3)
    low = torch.minimum(a[..., 2], b[..., 2]) - r  # (..., T, C)
    return (low[..., moving] >= 0).flatten(-2).all(-1)


def end_capsules(kinematics) -> tuple[Tensor, Tensor, Tensor]:
    """The capsules on links rigidly attached to the end link (no joint between), in the end
    link's frame: ``a (C', 3)``, ``b (C', 3)``, ``radius (C',)`` float64."""
    names = kinematics.frame_names
    fixed = [names[-1]]
    for i in range(len(names) - 1, 0, -1):  # back from the end link until the last revolute joint
        if kinematics.chain.find_frame(names[i]).joint.joint_type != "fixed":
            fixed.append(names[i])
            break
        fixed.append(names[i - 1])
    caps = [c for c in PANDA_CAPSULES if c.link in fixed]
    frames = kinematics.frames(torch.zeros(kinematics.num_joints, dtype=torch.float64,
                                           device=kinematics.lower.device)).cpu()  # (F, 4, 4)
    rel = torch.linalg.inv(frames[-1]) @ frames  # (F, 4, 4) every frame in the end link's
    a, b, r = capsule_segments(rel, names, caps)
    return a, b, r


def end_volume_near(ee_frames: Tensor, env: Tensor, capsules: tuple[Tensor, Tensor, Tensor]) -> Tensor:
    """Per step, the horizontal distance between the can's axis and the end capsules' surfaces:
    ``ee_frames (..., T, 4, 4)``, ``env (..., 4)`` -> ``(..., T)`` (the can's radius not
    subtracted, so that it reads like the end effector's distance to the axis)."""
    a, b, r = (x.to(ee_frames) for x in capsules)  # (C, 3), (C, 3), (C,)
    rot, pos = ee_frames[..., None, :2, :3], ee_frames[..., None, :2, 3]  # (..., T, 1, 2, 3), (..., T, 1, 2)
    pa = (rot @ a[:, :, None])[..., 0] + pos  # (..., T, C, 2)
    pb = (rot @ b[:, :, None])[..., 0] + pos
    c = env[..., None, None, 0:2]  # (..., 1, 1, 2)
    d = pb - pa
    u = (((c - pa) * d).sum(-1) / d.square().sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)  # (..., T, C)
    dist = (c - pa - u[..., None] * d).norm(dim=-1) - r  # (..., T, C)
    return dist.amin(-1)
