"""The arm task (Sec. IV-C): an arm reaches a target on a table around a can.

Everything here is about the task, not the robot (:mod:`protorch.robots`): where the can and the
target are drawn (:mod:`.workspace`), the IK demonstrations and detour paths (:mod:`.demos`), the
objectives' deviation (:mod:`.deviation`), the collision checks (:mod:`.collision`,
:mod:`.geometry`) and the prior ProMPs on a grid (:mod:`.priors`).
"""

from .reach import LEFT, RIGHT, SIDES, ArmReachTask

__all__ = ["ArmReachTask", "LEFT", "RIGHT", "SIDES"]
