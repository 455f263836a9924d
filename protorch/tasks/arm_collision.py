"""How close the arm comes to the can and to the table, under the task's collision model
(:class:`~protorch.tasks.ArmReachTask`'s ``collision``).

* ``"skeleton"``: the segments between consecutive frame origins (base to tool centre point),
  zero thickness. The gap to the can is the segments' distance to the can's axis segment minus
  the can's radius; above the table means every frame but the base at ``z >= 0``.
* ``"volume"``: the Panda's link capsules (:data:`~protorch.robots.panda_volumes.PANDA_CAPSULES`,
  the same volumes the MuJoCo scene collides with). A capsule's gap to the can is its segment's
  exact distance to the can's axis segment
  (:func:`~protorch.tasks.arm_geometry.segment_axis_distance`) minus the capsule's radius minus
  the can's radius. This treats the can as a capsule (its flat top rounded by its radius), so the
  check is exact beside the can and conservative by at most the can's radius over its top; a
  gap ``> 0`` guarantees that capsule and cylinder do not touch. Above the table means the lowest
  point of every capsule not on a base link (:data:`~protorch.robots.panda_volumes.PANDA_BASE_LINKS`)
  at ``z >= 0``.

The task's success asks ``gap > margin`` at every step; the moving test places a moved can only
where ``gap > place_clearance``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..robots.panda_volumes import PANDA_BASE_LINKS, PANDA_CAPSULES, capsule_index, capsule_segments
from .arm_geometry import segment_axis_distance

__all__ = ["COLLISIONS", "check_collision", "check_volumes", "frames_gap", "above_table"]

COLLISIONS = ("skeleton", "volume")


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
    d = segment_axis_distance(a, b, axis, 0.0, task.can_height) - r  # (..., T, C)
    return d.flatten(-2).amin(-1) - task.can_radius


def above_table(task, frames: Tensor) -> Tensor:
    """Whether the arm (under ``task.collision``) stays above the table top ``z = 0`` at every
    step: ``frames (..., T, F, 4, 4) -> (...)`` bool."""
    if task.collision == "skeleton":
        return (frames[..., 1:, 2, 3] >= 0).flatten(-2).all(-1)
    moving = torch.tensor([c.link not in PANDA_BASE_LINKS for c in PANDA_CAPSULES], device=frames.device)
    a, b, r = capsule_segments(frames, task.kinematics.frame_names)  # (..., T, C, 3)
    low = torch.minimum(a[..., 2], b[..., 2]) - r  # (..., T, C)
    return (low[..., moving] >= 0).flatten(-2).all(-1)
