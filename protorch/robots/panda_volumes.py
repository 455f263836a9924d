"""The Panda's bodies: the volumes the arm occupies and the inertial parameters it moves with.

One definition read by both the planner's collision check
(:class:`~protorch.tasks.ArmReachTask` with ``collision="volume"``) and the MuJoCo scene
(:mod:`protorch.sim.scene`), so planning and physics judge the same volumes.

**Capsules** (:data:`PANDA_CAPSULES`): each link's volume as one to three capsules, a segment
``a -> b`` in the link's own frame (the frames of :data:`~protorch.robots.PANDA_URDF`, which
are Franka's: the same joint origins as ``franka_description``) and a radius, metres. They were
fitted to Franka Emika's own meshes of the Panda ("fer" in ``frankaemika/franka_description``):
every vertex of a link's visual mesh and of its collision mesh is inside the link's capsules
(the enclosing capsules of least total volume found by a local search), the radii rounded up
to the millimetre. The hand's capsules also hold both fingers, fully open (4 cm each). Coverage,
measured by ``python benchmarks/panda_volumes.py --meshes <franka_description checkout>``: the
visual meshes' vertices 100 % inside; points sampled on the collision meshes' triangles
93-100 % inside, the largest protrusion 22 mm, at the elbow (links 3 and 4, the flat webs of
Franka's collision hull between the two joint housings); at the hand, link 7 and link 5 at most
3 mm. The capsules are thicker than the links (radius 5.0-6.9 cm where Franka's cylinders have
5.5 cm): a conservative volume.

**Inertial parameters** (:data:`PANDA_INERTIALS`): mass (kg), centre of mass (m, link frame)
and inertia about the centre of mass ``(xx, yy, zz, xy, xz, yz)`` (kg m^2, link frame) of every
link. They are the identified values of C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano and
A. De Luca, "Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible
Parameters Using Penalty-Based Optimization", IEEE Robotics and Automation Letters 4(4), 2019,
as published in ``franka_ros`` (``franka_description/robots/common/inertial.yaml``) and used by
MuJoCo Menagerie's Panda; the hand's are that file's. The two fingers (15 g each) are added to
the hand as point masses at their open positions.

**Drives**: :data:`PANDA_TORQUE_LIMITS` (N m, Franka's data sheet, the URDF's ``effort``);
joint damping (N m s / rad) and rotor armature (kg m^2) as in MuJoCo Menagerie's Panda.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

__all__ = ["Capsule", "Inertial", "PANDA_CAPSULES", "PANDA_INERTIALS", "PANDA_TORQUE_LIMITS", "PANDA_DAMPING",
           "PANDA_ARMATURE", "PANDA_FINGER_OPENING", "PANDA_FINGER_MASS", "PANDA_FINGER_OFFSET", "PANDA_BASE_LINKS",
           "capsule_index", "capsule_segments"]


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


PANDA_CAPSULES: tuple[Capsule, ...] = (
    Capsule("panda_link0", (-0.124, -0.0415, 0.028), (-0.1265, 0.0415, 0.029), 0.056),
    Capsule("panda_link0", (-0.021, 0.0, 0.0305), (-0.003, 0.0, 0.058), 0.103),
    Capsule("panda_link1", (0.0, 0.0, -0.162), (-0.001, -0.0255, -0.073), 0.068),
    Capsule("panda_link1", (0.0, -0.0375, 0.0), (0.001, -0.064, -0.003), 0.067),
    Capsule("panda_link2", (0.0015, -0.0755, 0.022), (0.0, -0.165, 0.0), 0.068),
    Capsule("panda_link2", (0.0, 0.0, 0.041), (-0.0015, -0.0035, 0.062), 0.069),
    Capsule("panda_link3", (0.0, 0.0, -0.0985), (0.0105, -0.0005, -0.06), 0.062),
    Capsule("panda_link3", (0.0815, 0.0315, -0.0005), (0.0765, 0.0575, -0.005), 0.065),
    Capsule("panda_link4", (-0.0005, 0.0005, 0.0315), (-0.0065, 0.005, 0.0575), 0.065),
    Capsule("panda_link4", (-0.072, 0.06, -0.0005), (-0.0825, 0.1015, 0.0), 0.063),
    Capsule("panda_link5", (0.0, 0.0065, -0.233), (0.0, 0.0645, 0.0035), 0.068),
    Capsule("panda_link5", (-0.001, 0.0935, -0.1475), (-0.0005, 0.088, -0.174), 0.052),
    Capsule("panda_link6", (0.0035, 0.0005, 0.0065), (0.025, 0.0075, 0.011), 0.056),
    Capsule("panda_link6", (0.087, -0.027, 0.0005), (0.078, 0.0415, -0.001), 0.056),
    Capsule("panda_link7", (-0.005, -0.005, 0.0735), (0.033, 0.033, 0.0815), 0.050),
    Capsule("panda_hand", (0.0, -0.08, 0.0045), (0.0, 0.0845, 0.0105), 0.033),
    Capsule("panda_hand", (0.0, -0.093, 0.052), (0.0, 0.087, 0.053), 0.029),
    Capsule("panda_hand", (0.0, -0.0535, 0.1015), (0.0, 0.0535, 0.1015), 0.013),
)

PANDA_INERTIALS: dict[str, Inertial] = {
    "panda_link0": Inertial(0.629769, (-0.041018, -0.00014, 0.049974),
                            (0.00315, 0.00388, 0.004285, 8.2904e-07, 0.00015, 8.2299e-06)),
    "panda_link1": Inertial(4.970684, (0.003875, 0.002081, -0.04762),
                            (0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169)),
    "panda_link2": Inertial(0.646926, (-0.003141, -0.02872, 0.003495),
                            (0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704)),
    "panda_link3": Inertial(3.228604, (0.027518, 0.039252, -0.066502),
                            (0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805)),
    "panda_link4": Inertial(3.587895, (-0.05317, 0.104419, 0.027454),
                            (0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641)),
    "panda_link5": Inertial(1.225946, (-0.011953, 0.041065, -0.038437),
                            (0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229)),
    "panda_link6": Inertial(1.666555, (0.060149, -0.014117, -0.010517),
                            (0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341)),
    "panda_link7": Inertial(0.735522, (0.010517, -0.004252, 0.061597),
                            (0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741)),
    "panda_hand": Inertial(0.73, (-0.01, 0.0, 0.03), (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0)),
}
PANDA_FINGER_MASS = 0.015  # kg each (inertial.yaml)
PANDA_FINGER_OFFSET = 0.0584  # m along the hand's z to the fingers' base (franka_description)
PANDA_FINGER_OPENING = 0.04  # m, each finger from the hand's centre plane (fully open)
PANDA_TORQUE_LIMITS = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)  # N m
PANDA_DAMPING = 1.0  # N m s / rad, every joint
PANDA_ARMATURE = 0.1  # kg m^2, every joint
PANDA_BASE_LINKS = ("panda_link0",)  # fixed to the table: no table check for them


def capsule_index(frame_names: Sequence[str], capsules: Sequence[Capsule] = PANDA_CAPSULES) -> list[int]:
    """The frame each capsule rides on, as indices into ``frame_names``; a clear error for a link
    the chain does not have."""
    names = list(frame_names)
    missing = sorted({c.link for c in capsules} - set(names))
    if missing:
        raise ValueError(f"the arm's frames {names} have no link {missing[0]!r} that a capsule rides on")
    return [names.index(c.link) for c in capsules]


def capsule_segments(frames: Tensor, frame_names: Sequence[str], capsules: Sequence[Capsule] = PANDA_CAPSULES
                     ) -> tuple[Tensor, Tensor, Tensor]:
    """The capsules in the base frame: ``frames (..., F, 4, 4)`` (e.g.
    :meth:`~protorch.robots.ArmKinematics.frames`) -> ``a (..., C, 3)``, ``b (..., C, 3)``,
    ``radius (C,)``."""
    idx = torch.tensor(capsule_index(frame_names, capsules), device=frames.device)
    kw = dict(dtype=frames.dtype, device=frames.device)
    pts = torch.tensor([[c.a, c.b] for c in capsules], **kw)  # (C, 2, 3)
    mats = frames.index_select(-3, idx)  # (..., C, 4, 4)
    rot, pos = mats[..., :3, :3], mats[..., :3, 3]  # (..., C, 3, 3), (..., C, 3)
    ends = torch.einsum("...cij,ckj->...cki", rot, pts) + pos[..., None, :]  # (..., C, 2, 3)
    return ends[..., 0, :], ends[..., 1, :], torch.tensor([c.radius for c in capsules], **kw)
