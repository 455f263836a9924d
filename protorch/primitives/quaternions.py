"""The quaternion conversions protorch takes from ``pytorch_kinematics.transforms`` (unit
quaternions ``(..., 4)``, real part first), imported at their first use: importing
``pytorch_kinematics`` loads its IK module and matplotlib's pyplot (about a second), which a run
that never turns a quaternion (the point particle, the toy tasks) need not pay."""

from __future__ import annotations

from torch import Tensor

__all__ = ["axis_angle_to_quaternion", "quaternion_raw_multiply", "quaternion_to_matrix"]


def axis_angle_to_quaternion(axis_angle: Tensor) -> Tensor:
    """``(..., 3)`` axis times angle -> ``(..., 4)`` unit quaternion."""
    from pytorch_kinematics.transforms import axis_angle_to_quaternion as convert

    return convert(axis_angle)


def quaternion_raw_multiply(a: Tensor, b: Tensor) -> Tensor:
    """The Hamilton product ``a b`` of ``(..., 4)`` quaternions (not normalised)."""
    from pytorch_kinematics.transforms import quaternion_raw_multiply as multiply

    return multiply(a, b)


def quaternion_to_matrix(q: Tensor) -> Tensor:
    """``(..., 4)`` unit quaternions -> ``(..., 3, 3)`` rotation matrices."""
    from pytorch_kinematics.transforms import quaternion_to_matrix as convert

    return convert(q)
