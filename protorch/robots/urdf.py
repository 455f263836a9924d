"""Reading a URDF: its text from a path or XML (:func:`read_urdf`), the parsed ``<robot>``
(:func:`parse_urdf`), its links (:func:`urdf_links`), the rotation of an ``<origin rpy>``
(:func:`rpy_matrix`) and every ``<collision>`` element (:func:`collision_geometry`), which the
capsule fitter (:mod:`protorch.robots.capsules`) encloses. The shipped descriptions live beside this
file (:data:`ROBOTS_DIR`); :func:`default_chain` names the default robot's URDF and end link.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .meshes import resolve_mesh

__all__ = [
    "ROBOTS_DIR",
    "DEFAULT_ROBOT",
    "default_chain",
    "read_urdf",
    "parse_urdf",
    "urdf_links",
    "rpy_matrix",
    "CollisionGeometry",
    "collision_geometry",
    "COLLISION_KINDS",
    "shipped_yaml",
]

ROBOTS_DIR = Path(__file__).resolve().parent
DEFAULT_ROBOT = "panda"
COLLISION_KINDS = ("sphere", "capsule", "cylinder", "box", "mesh")


def shipped_yaml(name: str) -> dict | None:
    """The raw settings of a shipped description (``protorch/robots/<name>.yaml``, its ``urdf``
    resolved beside it); ``None`` where there is no such file."""
    import yaml

    path = ROBOTS_DIR / f"{name}.yaml"
    if not path.is_file():
        return None
    data = yaml.safe_load(path.read_text()) or {}
    if data.get("urdf") is not None:
        data["urdf"] = str((path.parent / data["urdf"]).resolve())
    return data


def default_chain() -> tuple[str, str]:
    """``(urdf path, end link)`` of the default robot (:data:`DEFAULT_ROBOT`)."""
    data = shipped_yaml(DEFAULT_ROBOT)
    return data["urdf"], data["end_link"]


def rpy_matrix(rpy) -> list[list[float]]:
    """The rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` of a URDF ``rpy`` triple, as nested lists."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def read_urdf(urdf: str | Path) -> tuple[str, str]:
    """``(text, where)`` of a URDF given as a path or as its XML text."""
    if isinstance(urdf, Path) or (isinstance(urdf, str) and not urdf.lstrip().startswith("<")):
        path = Path(urdf)
        if not path.is_file():
            raise FileNotFoundError(f"no URDF file at {path}")
        return path.read_text(), str(path)
    if not isinstance(urdf, str):
        raise TypeError(f"urdf must be a path or the URDF's XML text, got {type(urdf).__name__}")
    return urdf, "the given URDF text"


def parse_urdf(text: str, where: str = "the URDF") -> ET.Element:
    """A URDF's XML text parsed: its ``<robot>`` element (a ``ValueError`` naming ``where`` if it
    is not XML or not a URDF)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"{where} is not valid XML: {exc}") from None
    if root.tag != "robot":
        raise ValueError(
            f"{where} is not a URDF: its root element is <{root.tag}>, expected <robot>"
        )
    return root


def urdf_links(text: str, where: str = "the URDF") -> list[str]:
    """Names of the ``<link>`` elements of a URDF's XML text (a clear error if it is not XML)."""
    return [link.get("name") for link in parse_urdf(text, where).iter("link")]


@dataclass(frozen=True)
class CollisionGeometry:
    """One ``<collision>`` element: its ``link``, ``kind`` (one of sphere, capsule, cylinder, box,
    mesh), ``origin`` (4, 4) in the link frame and the geometry's attributes (``radius``,
    ``length``, ``size``, ``mesh`` path resolved on disk, ``scale``)."""

    link: str
    kind: str
    origin: np.ndarray = field(repr=False)
    radius: float = 0.0
    length: float = 0.0
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mesh: Path | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


def _floats(
    text: str | None, n: int, what: str, default: Sequence[float] | None = None
) -> tuple[float, ...]:
    if text is None:
        if default is None:
            raise ValueError(f"{what} is missing")
        return tuple(default)
    try:
        vals = tuple(float(v) for v in text.split())
    except ValueError:
        raise ValueError(f"{what} must be {n} numbers, got {text!r}") from None
    if n == 3 and len(vals) == 1:  # a uniform mesh scale
        vals = vals * 3
    if len(vals) != n:
        raise ValueError(f"{what} must be {n} numbers, got {text!r}")
    return vals


def _origin(elem, what: str) -> np.ndarray:
    """The 4x4 transform of an ``<origin xyz rpy>`` (URDF: ``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
    out = np.eye(4)
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return out
    x, y, z = _floats(o.get("xyz"), 3, f"{what} <origin xyz>", (0.0, 0.0, 0.0))
    rpy = _floats(o.get("rpy"), 3, f"{what} <origin rpy>", (0.0, 0.0, 0.0))
    out[:3, :3] = rpy_matrix(rpy)
    out[:3, 3] = (x, y, z)
    return out


def _mesh_path(filename: str, base: Path | None, mesh_dir: Path | None, what: str) -> Path:
    """A ``<mesh filename>`` on disk (:func:`protorch.robots.meshes.resolve_mesh`; ``mesh_dir`` is
    searched as a ``robot.packages`` folder)."""

    return resolve_mesh(filename, base, [mesh_dir] if mesh_dir is not None else [], what)


def collision_geometry(
    urdf: str | Path, *, mesh_dir: str | Path | None = None
) -> list[CollisionGeometry]:
    """Every ``<collision>`` of a URDF (a path or its XML text), in document order. Mesh paths are
    resolved here (a clear error for one that is not on disk); ``mesh_dir`` is where
    ``package://<pkg>/...`` paths live (default: the URDF's folder)."""
    text, where = read_urdf(urdf)
    urdf_links(text, where)  # a clear error for text that is not a URDF
    base = Path(where).parent if Path(where).is_file() else None
    mesh_dir = Path(mesh_dir) if mesh_dir is not None else None
    out = []
    for link in ET.fromstring(text).iter("link"):
        name = link.get("name")
        for i, col in enumerate(link.findall("collision")):
            what = f"{where}: link {name!r} <collision> {i + 1}"
            geom = col.find("geometry")
            shapes = [g for g in (geom if geom is not None else []) if g.tag in COLLISION_KINDS]
            if len(shapes) != 1:
                raise ValueError(
                    f"{what} must hold one of <{'>, <'.join(COLLISION_KINDS)}> in its <geometry>"
                )
            g, origin = shapes[0], _origin(col, what)
            if g.tag in ("sphere", "capsule", "cylinder"):
                radius = _floats(g.get("radius"), 1, f"{what} <{g.tag} radius>")[0]
                length = _floats(g.get("length"), 1, f"{what} <{g.tag} length>", (0.0,))[0]
                if radius <= 0 or length < 0 or (g.tag == "cylinder" and length <= 0):
                    raise ValueError(
                        f"{what} <{g.tag}> needs a positive radius and length, got {radius}, "
                        f"{length}"
                    )
                out.append(CollisionGeometry(name, g.tag, origin, radius=radius, length=length))
            elif g.tag == "box":
                size = _floats(g.get("size"), 3, f"{what} <box size>")
                if min(size) <= 0:
                    raise ValueError(f"{what} <box size> must be positive, got {size}")
                out.append(CollisionGeometry(name, "box", origin, size=size))
            else:
                path = _mesh_path(g.get("filename") or "", base, mesh_dir, what)
                scale = _floats(g.get("scale"), 3, f"{what} <mesh scale>", (1.0, 1.0, 1.0))
                out.append(CollisionGeometry(name, "mesh", origin, mesh=path, scale=scale))
    return out
