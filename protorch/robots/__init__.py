"""Robot descriptions shipped with protorch (kinematic chains only: joints and frames, no meshes).

``PANDA_URDF``: the Franka Emika Panda, written from its published Denavit-Hartenberg parameters
and joint limits (see the comment at the top of the file), with the hand and its tool centre
point (``panda_hand_tcp``) as the end link. Load it with :class:`protorch.robots.ArmKinematics`.
"""

from .kinematics import ArmKinematics
from .panda import (
           PANDA_DH,
           PANDA_END_LINK,
           PANDA_FLANGE,
           PANDA_LIMITS,
           PANDA_MAX_ACCELERATION,
           PANDA_MAX_VELOCITY,
           PANDA_TCP,
           PANDA_URDF,
)

__all__ = ["ArmKinematics", "PANDA_URDF", "PANDA_END_LINK", "PANDA_DH", "PANDA_LIMITS", "PANDA_MAX_VELOCITY",
           "PANDA_MAX_ACCELERATION", "PANDA_FLANGE", "PANDA_TCP"]
