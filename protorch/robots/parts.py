"""The parts of a robot description read from its settings and its URDF, for
:mod:`protorch.robots.loader`: :class:`RobotError` (the one-line refusal every bad setting gets),
per-joint vectors (:func:`joint_vector`), the links' inertials (:func:`urdf_inertials`), the
capsules (:func:`auto_capsules` fitted to the URDF's ``<collision>`` geometry, or given) and the
point masses."""

from __future__ import annotations

import functools
import math
import numbers
import xml.etree.ElementTree as ET
from pathlib import Path

from ..errors import ProtorchError
from .capsules import fit_capsules
from .description import Capsule, Inertial, PointMass
from .urdf import collision_geometry, rpy_matrix

__all__ = [
    "RobotError",
    "joint_vector",
    "urdf_inertials",
    "auto_capsules",
    "capsules_setting",
    "point_masses_setting",
]


class RobotError(ProtorchError, ValueError):
    """A robot setting refused; its message is one line naming the setting."""


def joint_vector(value, n: int, key: str, names, *, positive: bool = True) -> tuple[float, ...]:
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        value = [value] * n
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise RobotError(
            f"robot.{key}={value!r} must be a number or {n} numbers, one per joint {list(names)}"
        )
    out = []
    for v, name in zip(value, names):
        if (
            isinstance(v, bool)
            or not isinstance(v, numbers.Real)
            or not math.isfinite(float(v))
            or (float(v) <= 0 if positive else float(v) < 0)
        ):
            raise RobotError(
                f"robot.{key} has {v!r} for joint {name!r}: it must be a finite number "
                f"{'> 0' if positive else '>= 0'}"
            )
        out.append(float(v))
    return tuple(out)


def _floats(text: str | None, n: int, what: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in (text or "").split())
    except ValueError:
        raise RobotError(f"{what}={text!r} must be {n} numbers") from None
    if len(vals) != n:
        raise RobotError(f"{what}={text!r} must be {n} numbers")
    return vals


def _origin(el: ET.Element | None) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if el is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    return (
        _floats(el.get("xyz", "0 0 0"), 3, "<origin xyz>"),
        _floats(el.get("rpy", "0 0 0"), 3, "<origin rpy>"),
    )


def _apply(rot, xyz, p) -> tuple[float, float, float]:
    return tuple(sum(rot[i][k] * p[k] for k in range(3)) + xyz[i] for i in range(3))


def urdf_inertials(root: ET.Element) -> dict[str, Inertial]:
    """Every link's ``<inertial>`` as an :class:`Inertial` in the link frame (an inertial frame
    rotated by ``rpy`` has its inertia rotated into the link's)."""
    out = {}
    for link in root.iter("link"):
        el = link.find("inertial")
        if el is None:
            continue
        name = link.get("name")
        mass_el, inertia_el = el.find("mass"), el.find("inertia")
        if mass_el is None or inertia_el is None:
            raise RobotError(
                f"robot.urdf: link {name!r} has an <inertial> without <mass> or <inertia>"
            )
        xyz, rpy = _origin(el.find("origin"))
        try:
            mass = float(mass_el.get("value"))
            xx, xy, xz, yy, yz, zz = (
                float(inertia_el.get(k)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
            )
        except (TypeError, ValueError):
            raise RobotError(
                f"robot.urdf: link {name!r} has an <inertial> with a missing or non-numeric value"
            ) from None
        if any(rpy):
            rot = rpy_matrix(rpy)
            mat = [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]
            rm = [
                [sum(rot[i][k] * mat[k][j] for k in range(3)) for j in range(3)] for i in range(3)
            ]
            full = [
                [sum(rm[i][k] * rot[j][k] for k in range(3)) for j in range(3)] for i in range(3)
            ]
            xx, yy, zz, xy, xz, yz = (
                full[0][0],
                full[1][1],
                full[2][2],
                full[0][1],
                full[0][2],
                full[1][2],
            )
        out[name] = Inertial(mass, tuple(xyz), (xx, yy, zz, xy, xz, yz))
    return out


def auto_capsules(urdf: str | Path, links, where: str) -> dict[str, tuple[Capsule, ...]]:
    """Capsules fitted to the URDF's ``<collision>`` geometry of those ``links`` that have some
    (:func:`protorch.robots.capsules.fit_capsules`: cylinders, spheres, boxes and ``<capsule>``
    exactly, meshes with ``trimesh``); a geometry it cannot read is refused in one line naming the
    link. ``urdf``: a path, or a cleaned text (:func:`~protorch.robots.clean.clean_urdf`, its mesh
    paths absolute). Cached per URDF text: a robot loaded again reuses its fit."""
    if isinstance(urdf, Path) or not str(urdf).lstrip().startswith("<"):
        source = str(urdf)
        text = Path(urdf).read_text()
    else:
        source = text = str(urdf)
    return {
        link: tuple(Capsule(link, a, b, r) for a, b, r in caps)
        for link, caps in _fit_cached(text, source, tuple(links), where).items()
    }


@functools.lru_cache(maxsize=16)
def _fit_cached(text: str, urdf: str, links: tuple[str, ...], where: str) -> dict:
    try:
        have = {g.link for g in collision_geometry(urdf)}
        wanted = [n for n in links if n in have]
        return fit_capsules(urdf, links=wanted) if wanted else {}
    except (ValueError, FileNotFoundError, ImportError) as exc:
        raise RobotError(
            f"robot.capsules=auto: {where}: {exc}; give the capsules in robot.capsules"
        ) from None


def capsules_setting(value, path, frame_names, where) -> dict[str, tuple[Capsule, ...]]:
    if value in ("none", None, False):
        return {}
    if value == "auto":
        return auto_capsules(path, frame_names, where)
    if not isinstance(value, dict):
        raise RobotError(
            f"robot.capsules={value!r} must be auto, none or {{link: [{{a, b, radius}}, ...]}}"
        )
    out = {}
    for link, caps in value.items():
        if link not in frame_names:
            raise RobotError(f"robot.capsules has link {link!r}, not on the chain {frame_names}")
        if not isinstance(caps, (list, tuple)):
            raise RobotError(
                f"robot.capsules.{link} must be a list of {{a: [x, y, z], b: [x, y, z], radius: r}}"
            )
        items = []
        for i, c in enumerate(caps):
            try:
                a, b, r = (
                    tuple(float(v) for v in c["a"]),
                    tuple(float(v) for v in c["b"]),
                    float(c["radius"]),
                )
                ok = len(a) == 3 and len(b) == 3 and r > 0 and all(map(math.isfinite, (*a, *b, r)))
            except (TypeError, KeyError, ValueError):
                ok = False
            if not ok:
                raise RobotError(
                    f"robot.capsules.{link}[{i}]={c!r} must be {{a: [x, y, z], b: [x, y, z], "
                    f"radius: r > 0}}"
                )
            items.append(Capsule(link, a, b, r))
        out[link] = tuple(items)
    return out


def point_masses_setting(value, frame_names) -> tuple[PointMass, ...]:
    out = []
    for i, p in enumerate(value or []):
        try:
            pm = PointMass(
                str(p["link"]),
                tuple(float(v) for v in p["pos"]),
                float(p["mass"]),
                tuple(float(v) for v in p["inertia"]),
            )
            ok = len(pm.pos) == 3 and len(pm.inertia) == 3 and pm.mass > 0
        except (TypeError, KeyError, ValueError):
            ok = False
        if not ok:
            raise RobotError(
                f"robot.point_masses[{i}]={p!r} must be {{link, pos: [x, y, z], mass > 0, "
                "inertia: [ixx, iyy, izz]}}"
            )
        if pm.link not in frame_names:
            raise RobotError(
                f"robot.point_masses[{i}] is on link {pm.link!r}, not on the chain {frame_names}"
            )
        out.append(pm)
    return tuple(out)
