"""The Panda's kinematic constants: DH parameters, limits, the URDF shipped beside this file."""

from __future__ import annotations

from pathlib import Path

__all__ = ["PANDA_URDF", "PANDA_END_LINK", "PANDA_DH", "PANDA_LIMITS", "PANDA_MAX_VELOCITY",
           "PANDA_MAX_ACCELERATION", "PANDA_FLANGE", "PANDA_TCP"]

PANDA_URDF = Path(__file__).resolve().parent / "panda.urdf"
PANDA_END_LINK = "panda_hand_tcp"

# Craig's (modified) DH parameters, one row per joint: (a_{i-1} [m], d_i [m], alpha_{i-1} [rad])
PANDA_DH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -1.5707963267948966),
    (0.0, 0.316, 1.5707963267948966),
    (0.0825, 0.0, 1.5707963267948966),
    (-0.0825, 0.384, -1.5707963267948966),
    (0.0, 0.0, 1.5707963267948966),
    (0.088, 0.0, 1.5707963267948966),
)
PANDA_FLANGE = 0.107  # d of the fixed flange frame (link8) after joint 7
PANDA_TCP = (-0.7853981633974483, 0.1034)  # hand: yaw about the flange's z, then the TCP along z
PANDA_LIMITS = (
    (-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
    (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973),
)
PANDA_MAX_VELOCITY = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)  # rad/s
PANDA_MAX_ACCELERATION = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)  # rad/s^2 (data sheet)
