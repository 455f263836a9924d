"""Joint limits robot makers publish beyond what a URDF states (jerk, per-joint acceleration)."""

from __future__ import annotations

__all__ = ["FRANKA_JOINT_LIMITS"]

# Franka's published joint limits of the Panda / FR3 arm (rad/s, rad/s^2, rad/s^3), joints 1-7
FRANKA_JOINT_LIMITS = {
    "max_velocity": (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    "max_acceleration": (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
    "max_jerk": (7500.0,) * 7,
}
