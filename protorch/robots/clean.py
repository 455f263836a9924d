"""A URDF as it comes, made into the text protorch's readers (``pytorch_kinematics``, MuJoCo, the
capsule fit, the pictures) all take: :func:`clean_urdf`.

What it changes, each reported in :class:`Cleaned` ``.report`` (the run's summary and
``metrics.json["robot"]`` show it):

* an XML declaration (``<?xml ... encoding="utf-8"?>``, which ``pytorch_kinematics`` refuses) and
  comments are dropped;
* elements protorch does not read are dropped (``<transmission>``, ``<gazebo>``,
  ``<ros2_control>``, ``<sensor>``, a link's ``<contact>``, a joint's ``<mimic>`` or
  ``<safety_controller>``, ...): listed once, by name and count (``ignored``);
* every ``<mesh filename>`` is resolved to an absolute file
  (:func:`protorch.robots.meshes.resolve_mesh`;
  a missing one refused naming the link); a file MuJoCo cannot read whole (Collada ``.dae``, an
  OBJ of several objects) replaced by its merged STL copy in the cache (``converted``);
* every movable joint off the chain to the end link (fingers, grippers, anything past the end
  link) becomes a fixed joint at 0 or at ``locked[name]`` (``locked``), its links kept as bodies;
* a ``continuous`` joint on the chain becomes revolute with the limits ``limits[name]`` or
  ``[-pi, pi]`` (``continuous``);
* an inertia whose principal moments violate the triangle inequality (``A + B >= C``) is replaced
  by the isotropic one of the same trace, MuJoCo's ``balanceinertia`` (``balanced``; with
  ``balance=False`` refused instead);
* an inertia no body of the link's size and mass can have (a principal moment above
  ``mass * d^2``, ``d`` the farthest point of the link's geometry from its centre of mass, or a
  massless link with an inertia) is replaced by the inertia of the geometry's convex hull, solid, of
  the link's mass, about its centre of mass (``implausible``); a massless link's ``<inertial>``
  is dropped (a massless body has no inertia).

A file needing none of this is returned as it is (``changed`` false).
"""

from __future__ import annotations

import logging
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ProtorchError
from .meshes import load_mesh, mujoco_mesh, resolve_mesh
from .urdf import rpy_matrix

__all__ = ["CleanError", "Cleaned", "clean_urdf", "end_link_candidates", "urdf_chain"]

log = logging.getLogger(__name__)

_DECL = re.compile(r"^\s*<\?xml[^>]*\?>\s*")
_KEEP = {
    "robot": {"link", "joint", "material"},
    "link": {"inertial", "visual", "collision"},
    "joint": {"origin", "parent", "child", "axis", "limit", "dynamics"},
    "visual": {"origin", "geometry", "material"},
    "collision": {"origin", "geometry"},
}
CONTINUOUS_LIMITS = (-math.pi, math.pi)


class CleanError(ProtorchError, ValueError):
    """A URDF protorch cannot use; one line naming the file and the element."""


@dataclass
class Cleaned:
    """The cleaned ``text``, whether it differs from the file (``changed``) and what was done
    (``report``: ``ignored``, ``locked``, ``continuous``, ``balanced``, ``implausible``,
    ``converted``, ``meshes``)."""

    text: str
    changed: bool
    report: dict = field(default_factory=dict)


def urdf_chain(root: ET.Element, end_link: str) -> list[ET.Element]:
    """The joints from the URDF's root link to ``end_link``, in order (``end_link`` must be a
    link)."""
    by_child = {
        j.find("child").get("link"): j for j in root.iter("joint") if j.find("child") is not None
    }
    chain, link = [], end_link
    while link in by_child:
        j = by_child[link]
        chain.append(j)
        link = j.find("parent").get("link")
        if len(chain) > len(by_child):
            raise CleanError(f"the joints form a loop above {end_link!r}")
    return chain[::-1]


def end_link_candidates(root: ET.Element) -> list[tuple[str, int]]:
    """The leaf links (no joint below them) with the number of movable joints to each,
    most first."""
    parents = {
        j.find("parent").get("link") for j in root.iter("joint") if j.find("parent") is not None
    }
    out = []
    for link in root.iter("link"):
        name = link.get("name")
        if name in parents:
            continue
        n = sum(j.get("type") != "fixed" for j in urdf_chain(root, name))
        out.append((name, n))
    return sorted(out, key=lambda t: -t[1])


def _floats(text, n, default):
    if text is None:
        return list(default)
    vals = [float(v) for v in text.split()]
    return vals * 3 if n == 3 and len(vals) == 1 else vals


def _rpy(rot: np.ndarray) -> tuple[float, float, float]:
    """The URDF ``rpy`` of a rotation ``R = Rz(y) Ry(p) Rx(r)``."""
    p = -math.asin(max(-1.0, min(1.0, float(rot[2, 0]))))
    if abs(math.cos(p)) > 1e-9:
        r, y = math.atan2(rot[2, 1], rot[2, 2]), math.atan2(rot[1, 0], rot[0, 0])
    else:  # gimbal lock: the roll carries the rest
        r, y = math.atan2(-rot[1, 2], rot[1, 1]), 0.0
    return r, p, y


def _axis_rotation(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _lock(joint: ET.Element, value: float) -> None:
    """Make ``joint`` fixed at ``value`` (rad or m along its axis), folded into its origin."""
    kind = joint.get("type")
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    xyz = np.array(_floats(origin.get("xyz"), 3, (0, 0, 0)))
    rot = np.array(rpy_matrix(_floats(origin.get("rpy"), 3, (0, 0, 0))))
    axis = _floats(
        joint.find("axis").get("xyz") if joint.find("axis") is not None else None, 3, (1, 0, 0)
    )
    if value:
        if kind == "prismatic":
            xyz = xyz + rot @ (value * np.asarray(axis, float) / np.linalg.norm(axis))
        elif kind in ("revolute", "continuous"):
            rot = rot @ _axis_rotation(axis, value)
        origin.set("xyz", " ".join(repr(float(v)) for v in xyz))
        origin.set("rpy", " ".join(repr(float(v)) for v in _rpy(rot)))
    joint.set("type", "fixed")
    for tag in ("limit", "dynamics", "axis"):
        for el in joint.findall(tag):
            joint.remove(el)


def _drop_unused(root: ET.Element) -> dict[str, int]:
    dropped: dict[str, int] = {}

    def visit(el: ET.Element, keep: set[str], where: str) -> None:
        for child in list(el):
            if not isinstance(child.tag, str):
                continue
            if child.tag not in keep:
                dropped[f"{where}<{child.tag}>" if where else f"<{child.tag}>"] = (
                    dropped.get(f"{where}<{child.tag}>" if where else f"<{child.tag}>", 0) + 1
                )
                el.remove(child)
            elif child.tag in _KEEP and child.tag != "robot":
                visit(child, _KEEP[child.tag], f"<{child.tag}> ")

    visit(root, _KEEP["robot"], "")
    return dropped


def _inertia_matrix(el: ET.Element) -> np.ndarray:
    xx, xy, xz, yy, yz, zz = (
        float(el.get(k, "0")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    )
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _set_inertia(el: ET.Element, mat: np.ndarray) -> None:
    for k, (i, j) in zip(
        ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    ):
        el.set(k, repr(float(mat[i, j])))


def _origin_matrix(el: ET.Element | None) -> np.ndarray:
    out = np.eye(4)
    o = el.find("origin") if el is not None else None
    if o is not None:
        out[:3, :3] = rpy_matrix(_floats(o.get("rpy"), 3, (0, 0, 0)))
        out[:3, 3] = _floats(o.get("xyz"), 3, (0, 0, 0))
    return out


def _geometry_points(link: ET.Element, vertices: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """Points of the link's collision geometry (visual where it has none), link frame ``(n, 3)``."""
    pts = []
    for tag in ("collision", "visual"):
        for item in link.findall(tag):
            g = item.find("geometry")
            shape = next((s for s in (g if g is not None else []) if isinstance(s.tag, str)), None)
            if shape is None:
                continue
            if shape.tag == "mesh":
                if shape.get("filename") not in vertices:
                    continue
                p = vertices[shape.get("filename")] * np.asarray(
                    _floats(shape.get("scale"), 3, (1, 1, 1))
                )
            elif shape.tag == "box":
                half = np.asarray(_floats(shape.get("size"), 3, (0, 0, 0))) / 2
                p = (
                    np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
                    * half
                )
            elif shape.tag in ("cylinder", "capsule", "sphere"):
                r = float(shape.get("radius", "0"))
                h = float(shape.get("length", "0")) / 2 + (r if shape.tag != "cylinder" else 0.0)
                if shape.tag == "sphere":
                    h = r
                p = np.array(
                    [[sx * r, sy * r, sz * h] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
                )
            else:
                continue
            m = _origin_matrix(item)
            pts.append(p @ m[:3, :3].T + m[:3, 3])
        if pts:
            break
    return np.concatenate(pts) if pts else None


def _hull_inertia(points: np.ndarray, mass: float, com: np.ndarray) -> np.ndarray | None:
    """The inertia about ``com`` of the points' convex hull, solid, of ``mass``."""
    import trimesh

    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception:  # noqa: BLE001 (qhull on a degenerate, flat cloud)
        return None
    if not hull.is_volume or hull.volume <= 0:
        return None
    inertia = np.asarray(hull.moment_inertia, float) * (
        mass / hull.volume
    )  # about the hull's centroid
    d = np.asarray(com, float) - np.asarray(hull.center_mass, float)
    return inertia + mass * (float(d @ d) * np.eye(3) - np.outer(d, d))


def _fix_inertias(
    root: ET.Element, balance: bool, where: str, vertices: Mapping[str, np.ndarray]
) -> tuple[list[str], list[str], bool]:
    balanced, implausible, changed_any = [], [], False
    for link in root.iter("link"):
        el = link.find("inertial")
        if el is None or el.find("inertia") is None or el.find("mass") is None:
            continue
        name = link.get("name")
        mass = float(el.find("mass").get("value", "0"))
        frame = _origin_matrix(el)
        mat = frame[:3, :3] @ _inertia_matrix(el.find("inertia")) @ frame[:3, :3].T  # link frame
        eig = np.linalg.eigvalsh(mat)
        if not mass > 0:
            if np.abs(mat).max() > 0:
                implausible.append(name)
            link.remove(
                el
            )  # a massless link has no inertial (MuJoCo refuses a zero inertia given explicitly)
            changed_any = True
            continue
        pts = _geometry_points(link, vertices)
        if pts is not None:
            dmax = float(np.linalg.norm(pts - frame[:3, 3], axis=1).max())
            if eig.max() > mass * dmax**2 * (1 + 1e-6):
                new = _hull_inertia(pts, mass, frame[:3, 3])
                if new is not None:
                    implausible.append(name)
                    _set_inertia(el.find("inertia"), frame[:3, :3].T @ new @ frame[:3, :3])
                    continue
        a, b, c = eig
        if eig.min() < 0 or c > (a + b) * (1 + 1e-9) + 1e-15:
            if not balance:
                raise CleanError(
                    f"{where}: link {name!r} has an inertia whose principal moments "
                    f"{[float(v) for v in eig]} violate A + B >= C (robot.balance_inertia=false "
                    "refuses "
                    "it; true replaces it by the isotropic inertia of the same trace)"
                )
            balanced.append(name)
            _set_inertia(el.find("inertia"), np.eye(3) * max(float(eig.sum()) / 3, 0.0))
    return balanced, implausible, changed_any


def clean_urdf(
    path: str | Path,
    end_link: str,
    *,
    locked: Mapping[str, float] | None = None,
    limits: Mapping[str, Sequence[float]] | None = None,
    packages: Sequence[str | Path] = (),
    balance: bool = True,
    where: str | None = None,
) -> Cleaned:
    """The URDF at ``path`` cleaned for the chain to ``end_link`` (module docstring). Refuses, in
    one line naming the file and the element (:class:`CleanError`, a ``FileNotFoundError`` for a
    mesh not found), what it cannot repair."""
    path = Path(path)
    where = where or f"robot.urdf={path}"
    raw = path.read_text()
    body = _DECL.sub("", raw, count=1)
    try:
        root = ET.fromstring(body)
    except ET.ParseError as exc:
        raise CleanError(f"{where} is not valid XML: {exc}") from None
    if root.tag != "robot":
        raise CleanError(
            f"{where} is not a URDF: its root element is <{root.tag}>, expected <robot>"
        )
    report: dict = {}
    changed = (
        "encoding" in raw[: len(raw) - len(body)]
    )  # what pytorch_kinematics (lxml) refuses in a str
    dropped = _drop_unused(root)
    if dropped:
        report["ignored"] = dropped
        log.info(
            "%s: ignored what protorch does not read: %s",
            where,
            ", ".join(f"{k} x{v}" for k, v in sorted(dropped.items())),
        )
        changed = True
    chain = {j.get("name") for j in urdf_chain(root, end_link)}
    locked = dict(locked or {})
    unknown = sorted(set(locked) - {j.get("name") for j in root.iter("joint")})
    if unknown:
        raise CleanError(f"robot.locked names {unknown[0]!r}, not a joint of {where}")
    on_chain = sorted(set(locked) & chain)
    if on_chain:
        raise CleanError(
            f"robot.locked names {on_chain[0]!r}, a joint of the chain to {end_link!r}; only "
            "joints off "
            "the chain can be locked"
        )
    report["locked"] = {}
    for j in root.iter("joint"):
        name, kind = j.get("name"), j.get("type")
        if name in chain or kind == "fixed":
            continue
        value = float(locked.get(name, 0.0))
        _lock(j, value)
        report["locked"][name] = value
        changed = True
    limits = dict(limits or {})
    report["continuous"] = {}
    for j in root.iter("joint"):
        if j.get("name") in chain and j.get("type") == "continuous":
            lo, hi = (float(v) for v in limits.get(j.get("name"), CONTINUOUS_LIMITS))
            lim = j.find("limit")
            if lim is None:
                lim = ET.SubElement(j, "limit")
            lim.set("lower", repr(lo))
            lim.set("upper", repr(hi))
            j.set("type", "revolute")
            report["continuous"][j.get("name")] = [lo, hi]
            changed = True
    report["meshes"], report["converted"] = 0, []
    vertices: dict[
        str, np.ndarray
    ] = {}  # every mesh read once: an unreadable one refused here, before any work
    for link in root.iter("link"):
        for i, mesh in enumerate(link.iter("mesh")):
            what = f"{where}: link {link.get('name')!r} <mesh> {i + 1}"
            src = resolve_mesh(mesh.get("filename") or "", path.parent, packages, what)
            out, converted = mujoco_mesh(src, what)
            if str(out) not in vertices:
                vertices[str(out)] = np.asarray(
                    load_mesh(out, f"{what} ({src})").vertices, dtype=np.float64
                )
            report["meshes"] += 1
            if converted:
                report["converted"].append(f"{src.name} -> {out}")
            if mesh.get("filename") != str(out):
                mesh.set("filename", str(out))
                changed = True
    balanced, implausible, dropped_massless = _fix_inertias(root, balance, where, vertices)
    report["balanced"], report["implausible"] = balanced, implausible
    if balanced:
        log.warning("%s: inertias balanced (A + B >= C violated): %s", where, ", ".join(balanced))
    if implausible:
        log.warning(
            "%s: inertias no body of the link's size and mass can have, replaced by the solid "
            "convex hull "
            "of its geometry: %s",
            where,
            ", ".join(implausible),
        )
    changed |= bool(balanced or implausible or dropped_massless)
    return Cleaned(ET.tostring(root, encoding="unicode") if changed else raw, changed, report)
