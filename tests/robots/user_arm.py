"""A user's own arm, not shipped with protorch: a 6-DoF elbow arm with a ZYZ-like wrist, collision
cylinders, inertials and a tool link, written as a URDF for the tests (docs/your_own_robot.md's
example is the same arm). :func:`write_user_arm` returns the file and a home pose that puts the
tool 10 cm (times ``scale``) above the table at x = 0.4 m (times ``scale``), pointing down."""

from __future__ import annotations

import math
from pathlib import Path

# (name, parent, child, axis, origin z, child collision (kind, radius, length, centre z), mass)
_JOINTS = (
    ("shoulder_pan", "base_link", "shoulder", "0 0 1", 0.1, ("cylinder", 0.06, 0.2, 0.1), 3.0),
    ("shoulder_lift", "shoulder", "upper_arm", "0 1 0", 0.2, ("cylinder", 0.05, 0.45, 0.225), 4.0),
    ("elbow", "upper_arm", "forearm", "0 1 0", 0.45, ("cylinder", 0.045, 0.4, 0.2), 2.5),
    ("wrist_1", "forearm", "wrist_1_link", "0 0 1", 0.4, ("sphere", 0.045, 0.0, 0.0), 1.0),
    ("wrist_2", "wrist_1_link", "wrist_2_link", "0 1 0", 0.0, ("cylinder", 0.04, 0.1, 0.05), 0.8),
    ("wrist_3", "wrist_2_link", "wrist_3_link", "0 0 1", 0.1, ("cylinder", 0.04, 0.04, 0.02), 0.4),
)
TOOL = 0.06  # tool0 beyond wrist_3's origin


def _link(name: str, collision, mass: float | None, s: float, visual: str | None = None) -> str:
    kind, r, length, cz = collision
    geom = (
        f'<cylinder radius="{r * s}" length="{length * s}"/>'
        if kind == "cylinder"
        else f'<sphere radius="{r * s}"/>'
    )
    out = [
        f'  <link name="{name}">',
        f'    <collision><origin xyz="0 0 {cz * s}"/><geometry>{geom}</geometry></collision>',
    ]
    if visual is not None:
        out.append(f'    <visual><geometry><mesh filename="{visual}"/></geometry></visual>')
    if mass is not None:
        i = (
            mass * (3 * (r * s) ** 2 + (length * s) ** 2) / 12
        )  # a solid cylinder's transverse moments
        out.append(
            f'    <inertial><origin xyz="0 0 {cz * s}" rpy="0 0 0"/><mass value="{mass}"/>'
            f'<inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="'
            f'{mass * (r * s) ** 2 / 2}"/></inertial>'
        )
    return "\n".join(out + ["  </link>"])


def user_arm_urdf(
    *,
    scale: float = 1.0,
    inertials: bool = True,
    fixed: tuple[str, ...] = (),
    visual: str | None = None,
) -> str:
    """The URDF text; ``fixed``: joints made fixed (a chain with fewer joints); ``visual``: a mesh
    file drawn as the forearm's ``<visual>``."""
    s = scale
    parts = [
        '<?xml version="1.0"?>',
        '<robot name="my_arm">',
        _link("base_link", ("cylinder", 0.08, 0.1, 0.05), 4.0 if inertials else None, s),
    ]
    for name, parent, child, axis, z, col, mass in _JOINTS:
        parts.append(
            _link(
                child, col, mass if inertials else None, s, visual if child == "forearm" else None
            )
        )
        kind = "fixed" if name in fixed else "revolute"
        lim = (
            f'<limit lower="{-math.pi}" upper="{math.pi}" velocity="2.0" effort="'
            f'{150 if mass > 2 else 30}"/>'
            if kind == "revolute"
            else ""
        )
        parts.append(
            f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 {z * s}" rpy="0 0 0"/><axis xyz="{axis}"/>{lim}</joint>'
        )
    parts += [
        '  <link name="tool0"/>',
        '  <joint name="tool_joint" type="fixed"><parent link="wrist_3_link"/><child '
        'link="tool0"/>'
        f'<origin xyz="0 0 {TOOL * s}"/></joint>',
        "</robot>",
    ]
    return "\n".join(parts) + "\n"


def user_arm_home() -> list[float]:
    """Joint angles putting tool0 at (0.4, 0, 0.1) (times the scale), pointing down, elbow up."""
    shoulder_z = 0.3
    l1, l2, hand = 0.45, 0.4, 0.1 + TOOL
    x, z = 0.4, 0.1 + hand - shoulder_z  # the wrist centre relative to the shoulder
    c3 = (x * x + z * z - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    q3 = math.acos(
        c3
    )  # the elbow bent forwards: the upper arm leans back, the forearm reaches out and down
    q2 = math.atan2(x, z) - math.atan2(l2 * math.sin(q3), l1 + l2 * math.cos(q3))
    q5 = math.pi - q2 - q3  # the tool along -z
    return [0.0, round(q2, 6), round(q3, 6), 0.0, round(q5, 6), 0.0]


def write_user_arm(folder: Path, name: str = "my_arm.urdf", **kwargs) -> Path:
    path = Path(folder) / name
    path.write_text(user_arm_urdf(**kwargs))
    return path
