"""Robot descriptions: what protorch knows of an arm, and the only place that names one.

:class:`Robot` (:mod:`protorch.robots.description`) is one typed description of a serial arm:
URDF, end link (tool centre point), home configuration, joint limits (position, velocity,
acceleration, torque), damping and armature, collision capsules per link, inertials and a display
name. :func:`load_robot` makes it from a shipped description (``protorch/robots/<name>.yaml``
beside its URDF: ``panda``, the Franka Emika Panda, the default) or from the ``robot.*`` settings
of the command line (:mod:`protorch.robots.loader`; docs/your_own_robot.md).
:class:`ArmKinematics` is the chain's batched forward kinematics (``pytorch_kinematics``).
"""

from .description import Capsule, Inertial, PointMass, Robot, capsule_index, capsule_segments
from .kinematics import ArmKinematics, PointPlan
from .loader import ROBOTS_DIR, RobotError, check_inertials, load_robot, shipped_robots

__all__ = [
    "ArmKinematics",
    "PointPlan",
    "Robot",
    "Capsule",
    "Inertial",
    "PointMass",
    "RobotError",
    "ROBOTS_DIR",
    "load_robot",
    "shipped_robots",
    "check_inertials",
    "capsule_index",
    "capsule_segments",
]
