"""A robot arm as protorch reads it: :class:`Robot`, one typed description that every layer
(kinematics, the arm task's demonstrations, objectives and collision checks, the moving test's
limits, the MuJoCo scene, the renders, the viewer, the figures) reads, so that no code outside
``protorch.robots`` names a particular arm's links or numbers.

A description is made by :func:`protorch.robots.load_robot` from a shipped yaml
(``protorch/robots/<name>.yaml``, e.g. the Panda's) or from the ``robot.*`` settings of the
command line (``robot=custom robot.urdf=my_arm.urdf robot.end_link=tool0 robot.home=[...]``):
docs/your_own_robot.md. It holds

* the URDF (``urdf``: a file path) and the chain's end link (``end_link``: the tool centre
  point), the chain's joints in order (``joint_names``) and the home (start) configuration;
* per joint: position limits, velocity limits (rad/s) and torque limits (N m), from the URDF's
  ``<limit lower upper velocity effort>``; acceleration limits (rad/s^2), joint damping
  (N m s / rad) and rotor armature (kg m^2) from the description;
* the collision volumes: capsules per link (:class:`Capsule`, a segment in the link frame and a
  radius), the links fixed to the table (``base_links``: no table check, no table contact) and
  the link whose capsules the volume objective reads besides those rigid with the end link
  (``forearm_link``, or none);
* the links' inertials (:class:`Inertial`, from the URDF's ``<inertial>``) and point masses the
  URDF does not carry (:class:`PointMass`, e.g. the Panda's fingers);
* a display name (figure titles, ``metrics.json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import torch
from torch import Tensor

from .kinematics import ArmKinematics

__all__ = ["Capsule", "Inertial", "PointMass", "Robot", "capsule_index", "capsule_segments"]


@dataclass(frozen=True)
class Capsule:
    """A capsule on ``link``: the segment ``a -> b`` (link frame, m) and ``radius`` (m)."""

    link: str
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class Inertial:
    """A link's ``mass`` (kg), centre of mass ``com`` (m) and inertia about it
    ``(xx, yy, zz, xy, xz, yz)`` (kg m^2), in the link frame."""

    mass: float
    com: tuple[float, float, float]
    inertia: tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class PointMass:
    """A small body rigidly attached to ``link`` at ``pos`` (link frame, m): ``mass`` (kg) and
    principal ``inertia`` (kg m^2), e.g. a gripper finger the URDF does not carry."""

    link: str
    pos: tuple[float, float, float]
    mass: float
    inertia: tuple[float, float, float]


@dataclass(frozen=True)
class Robot:
    """A serial arm (module docstring). Made by :func:`~protorch.robots.load_robot`, which checks
    every field; ``settings`` is the plain dict it was loaded from (``load_robot(robot.settings)``
    gives the same robot: what a subprocess or a worker is handed)."""

    name: str
    urdf: Path
    end_link: str
    joint_names: tuple[str, ...]
    home: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    max_velocity: tuple[float, ...]
    max_acceleration: tuple[float, ...]
    max_torque: tuple[float, ...]
    damping: tuple[float, ...]
    armature: tuple[float, ...]
    capsules: Mapping[str, tuple[Capsule, ...]]
    base_links: tuple[str, ...]
    forearm_link: str | None
    inertials: Mapping[str, Inertial]
    point_masses: tuple[PointMass, ...] = ()
    max_jerk: tuple[float, ...] = ()  # rad/s^3 per joint: a policy's reference's limit
    settings: dict = field(default_factory=dict, compare=False, repr=False)
    text: str | None = field(
        default=None, compare=False, repr=False
    )  # the cleaned URDF (protorch.robots.clean)
    found: dict = field(
        default_factory=dict, compare=False, repr=False
    )  # what protorch found or defaulted

    @property
    def num_joints(self) -> int:
        """``J``, the chain's revolute joints."""
        return len(self.joint_names)

    @property
    def urdf_text(self) -> str:
        """The URDF as protorch reads it (:func:`~protorch.robots.clean.clean_urdf`: mesh paths
        absolute, off-chain joints locked, ...); the file's own text where nothing needed it."""
        return self.text if self.text is not None else Path(self.urdf).read_text()

    def capsule_list(self) -> tuple[Capsule, ...]:
        """Every capsule, link by link in the description's order."""
        return tuple(c for caps in self.capsules.values() for c in caps)

    def kinematics(self, dtype: torch.dtype = torch.float64, device=None):
        """The chain base -> end link (:class:`~protorch.robots.ArmKinematics`)."""
        return ArmKinematics(
            self.urdf if self.text is None else self.text,
            end_link=self.end_link,
            dtype=dtype,
            device=device,
        )

    def summary(self) -> dict:
        """What ``metrics.json`` records of the robot: name, URDF, end link, joints, home, and
        under ``found`` what protorch found or defaulted (end link, home, locked joints, balanced
        or replaced inertias, converted meshes, ignored tags, limits; absent where nothing)."""
        out = {
            "name": self.name,
            "urdf": str(self.urdf),
            "end_link": self.end_link,
            "joints": self.num_joints,
            "joint_names": list(self.joint_names),
            "home": list(self.home),
            "capsules": len(self.capsule_list()),
        }
        if self.found:
            out["found"] = self.found
        return out


def capsule_index(frame_names: Sequence[str], capsules: Sequence[Capsule]) -> list[int]:
    """The frame each capsule rides on, as indices into ``frame_names``; a clear error for a link
    the chain does not have."""
    names = list(frame_names)
    missing = sorted({c.link for c in capsules} - set(names))
    if missing:
        raise ValueError(
            f"the arm's frames {names} have no link {missing[0]!r} that a capsule rides on"
        )
    return [names.index(c.link) for c in capsules]


def capsule_segments(
    frames: Tensor, frame_names: Sequence[str], capsules: Sequence[Capsule]
) -> tuple[Tensor, Tensor, Tensor]:
    """The capsules in the base frame: ``frames (..., F, 4, 4)`` (e.g.
    :meth:`~protorch.robots.ArmKinematics.frames`) -> ``a (..., C, 3)``, ``b (..., C, 3)``,
    ``radius (C,)``."""
    idx = torch.tensor(capsule_index(frame_names, capsules), device=frames.device, dtype=torch.long)
    kw = dict(dtype=frames.dtype, device=frames.device)
    pts = torch.tensor([[c.a, c.b] for c in capsules], **kw).reshape(
        len(capsules), 2, 3
    )  # (C, 2, 3)
    mats = frames.index_select(-3, idx)  # (..., C, 4, 4)
    rot, pos = mats[..., :3, :3], mats[..., :3, 3]  # (..., C, 3, 3), (..., C, 3)
    ends = torch.einsum("...cij,ckj->...cki", rot, pts) + pos[..., None, :]  # (..., C, 2, 3)
    return ends[..., 0, :], ends[..., 1, :], torch.tensor([c.radius for c in capsules], **kw)
