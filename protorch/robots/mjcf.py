"""An arm described in MuJoCo's format (MJCF, ``robot.mjcf=PATH``), read by MuJoCo and written
once as an equivalent URDF that every other reader (kinematics, capsules, the MuJoCo scene,
the pictures) takes as it takes a user's URDF: :func:`mjcf_urdf`.

MuJoCo compiles the file (its includes, defaults, ``fromto`` geoms, mesh assets and inertias
from geoms resolved), and the compiled model is written out body by body:

* each body a ``<link>`` of the body's name; its frame the body's, moved to its joint's anchor
  where the joint has one off the body's origin (the link's geoms and inertial moved with it, so
  the kinematics are MuJoCo's to round-off);
* each body's joint a ``<joint>``: a ``hinge`` ``revolute`` (its ``range``; ``continuous`` where
  the joint is not limited), a ``slide`` ``prismatic``, none ``fixed``; its torque limit the
  ``forcerange`` of the motor driving it, else the motor's ``gear`` times its ``ctrlrange``, else
  the joint's ``actuatorfrcrange`` (absent: the loader's stated default); MJCF has no velocity
  limit: :data:`MJCF_VELOCITY` is written (reported in the summary);
* each geom a ``<collision>`` (a geom that collides: ``contype`` or ``conaffinity`` set) or a
  ``<visual>`` (one that does not; where a body has no such geom its collision geoms are drawn):
  spheres, capsules, cylinders and boxes as themselves, ellipsoids as boxes around them, meshes as
  OBJ files of MuJoCo's compiled vertices beside the URDF; planes and height fields ignored;
* each body's mass, centre of mass and principal inertia an ``<inertial>``.

Bodies with a free joint (objects of a scene) and mocap bodies are left out, with what else is
ignored in the report. A body with a ball joint or with several joints is refused naming the body.
The URDF and its meshes go to ``<cache>/mjcf/<hash of the file>/``
(:func:`protorch.robots.meshes.cache_dir`).
"""

from __future__ import annotations

import hashlib
import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import ProtorchError
from .meshes import cache_dir

__all__ = ["MjcfError", "MJCF_VELOCITY", "mjcf_urdf", "mjcf_to_urdf", "quat_rpy"]

# rad/s: every joint's <limit velocity> (MJCF has none; the kinematics, the moving test and the
# controller read the URDF's, so it must be a working speed: robot.max_velocity sets the limits)
MJCF_VELOCITY = 2.0


class MjcfError(ProtorchError, ValueError):
    """An MJCF file protorch cannot use; one line naming the file and the element."""


def quat_rpy(quat) -> tuple[float, float, float]:
    """A unit quaternion ``(w, x, y, z)`` as URDF's ``rpy`` (``R = Rz(y) Ry(p) Rx(r)``)."""
    w, x, y, z = (float(v) for v in quat)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    r20 = 2 * (x * z - w * y)
    r21, r22 = 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    r10, r00 = 2 * (x * y + w * z), 1 - 2 * (y * y + z * z)
    if abs(r20) < 1 - 1e-12:
        return math.atan2(r21, r22), math.asin(-r20), math.atan2(r10, r00)
    r01, r11 = 2 * (x * y - w * z), 1 - 2 * (x * x + z * z)  # gimbal lock: roll folded into yaw
    return 0.0, math.copysign(math.pi / 2, -r20), math.atan2(-r01, r11)


def _mat(quat) -> np.ndarray:
    w, x, y, z = (float(v) for v in quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _f(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _origin(parent: ET.Element, xyz, quat=(1.0, 0.0, 0.0, 0.0)) -> None:
    ET.SubElement(parent, "origin", xyz=_f(xyz), rpy=_f(quat_rpy(quat)))


def _name(model, kind, i: int, fallback: str) -> str:
    import mujoco

    return mujoco.mj_id2name(model, kind, i) or fallback


def _effort(model, joint: int) -> float | None:
    """The joint's torque limit from the actuators driving it, else its actuatorfrcrange."""
    import mujoco

    best, by_joint = None, int(mujoco.mjtTrn.mjTRN_JOINT)
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) != by_joint or int(model.actuator_trnid[a, 0]) != joint:
            continue
        gear = abs(float(model.actuator_gear[a, 0]))
        if model.actuator_forcelimited[a]:
            value = float(np.abs(model.actuator_forcerange[a]).max())
        elif model.actuator_ctrllimited[a] and model.actuator_biastype[a] == 0:
            value = gear * float(np.abs(model.actuator_ctrlrange[a]).max())
        else:
            continue
        best = value if best is None else max(best, value)
    if best is None and model.jnt_actfrclimited[joint]:
        best = float(np.abs(model.jnt_actfrcrange[joint]).max())
    return best if best is not None and best > 0 else None


def _write_obj(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in verts.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces.tolist()]
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


def _geom(model, g: int, link: ET.Element, offset: np.ndarray, folder: Path, tag: str) -> bool:
    """``g`` as a ``<tag>`` (visual or collision) of ``link``; False for a kind left out."""
    import mujoco

    t, size = int(model.geom_type[g]), model.geom_size[g]
    T = {  # the geom kinds' codes
        k: int(getattr(mujoco.mjtGeom, k))
        for k in (
            "mjGEOM_SPHERE",
            "mjGEOM_CAPSULE",
            "mjGEOM_CYLINDER",
            "mjGEOM_BOX",
            "mjGEOM_ELLIPSOID",
            "mjGEOM_MESH",
        )
    }
    if t == T["mjGEOM_SPHERE"]:
        shape = ("sphere", {"radius": repr(float(size[0]))})
    elif t in (T["mjGEOM_CAPSULE"], T["mjGEOM_CYLINDER"]):
        kind = "capsule" if t == T["mjGEOM_CAPSULE"] else "cylinder"
        shape = (kind, {"radius": repr(float(size[0])), "length": repr(2 * float(size[1]))})
    elif t in (T["mjGEOM_BOX"], T["mjGEOM_ELLIPSOID"]):
        shape = ("box", {"size": _f(2 * size[:3])})
    elif t == T["mjGEOM_MESH"]:
        mesh = int(model.geom_dataid[g])
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
        path = folder / f"mesh{mesh}.obj"
        if not path.is_file():
            _write_obj(path, model.mesh_vert[v0 : v0 + nv], model.mesh_face[f0 : f0 + nf])
        shape = ("mesh", {"filename": str(path)})
    else:
        return False
    el = ET.SubElement(link, tag)
    _origin(el, model.geom_pos[g] - offset, model.geom_quat[g])
    ET.SubElement(ET.SubElement(el, "geometry"), shape[0], attrib=shape[1])
    return True


def _at_origin(model, b: int) -> bool:
    """Whether body ``b`` is fixed at its parent's origin, unrotated (a base that can be the
    URDF's root link)."""
    return (
        model.body_jntnum[b] == 0
        and not np.any(model.body_pos[b])
        and np.array_equal(model.body_quat[b], [1.0, 0.0, 0.0, 0.0])
    )


def _kept_bodies(model, where: str, ignored: dict) -> list[int]:
    """The bodies written (a body with a free joint, a mocap body and their subtrees left out)."""
    import mujoco

    kept: list[int] = []
    dropped: set[int] = set()
    for b in range(1, model.nbody):
        parent = int(model.body_parentid[b])
        jnts = range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b])
        free = any(int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE) for j in jnts)
        if parent in dropped or free or model.body_mocapid[b] >= 0:
            dropped.add(b)
            if parent not in dropped:
                key = "free bodies" if free else "mocap bodies"
                ignored[key] = ignored.get(key, 0) + 1
            continue
        name = _name(model, mujoco.mjtObj.mjOBJ_BODY, b, f"body{b}")
        if model.body_jntnum[b] > 1:
            raise MjcfError(
                f"{where}: body {name!r} has {model.body_jntnum[b]} joints; protorch reads one "
                "joint per body (split the body)"
            )
        if model.body_jntnum[b] == 1 and int(model.jnt_type[model.body_jntadr[b]]) not in (
            int(mujoco.mjtJoint.mjJNT_HINGE),
            int(mujoco.mjtJoint.mjJNT_SLIDE),
        ):
            raise MjcfError(
                f"{where}: body {name!r} has a ball joint; protorch reads hinge and slide joints"
            )
        kept.append(b)
    return kept


def mjcf_to_urdf(path: str | Path, folder: Path, where: str | None = None) -> tuple[str, dict]:
    """``(URDF text, report)`` of the MJCF file at ``path`` (module docstring); its meshes are
    written into ``folder``. ``report``: ``file``, ``bodies``, ``geoms``, ``ignored`` (kind:
    count)."""
    import mujoco

    path = Path(path)
    where = where or f"robot.mjcf={path}"
    try:
        root_name = ET.parse(path).getroot().get("model") or path.stem
        model = mujoco.MjModel.from_xml_path(str(path))
    except ET.ParseError as exc:
        raise MjcfError(f"{where} is not valid XML: {exc}") from None
    except ValueError as exc:
        raise MjcfError(f"{where}: MuJoCo cannot read it: {str(exc).strip().splitlines()[0]}")
    ignored: dict = {}
    bodies = _kept_bodies(model, where, ignored)
    if not bodies:
        raise MjcfError(f"{where} has no body but the world's (and free or mocap bodies)")
    obj = mujoco.mjtObj
    names = {0: "mjcf_world"}  # not "world": MuJoCo takes a URDF link of that name as its own
    for b in bodies:
        names[b] = _name(model, obj.mjOBJ_BODY, b, f"body{b}")
    offsets = {0: np.zeros(3)}
    robot = ET.Element("robot", name=root_name)
    top = [b for b in bodies if model.body_parentid[b] == 0]
    root = top[0] if len(top) == 1 and _at_origin(model, top[0]) else 0
    if root == 0:  # the world a link of its own only where the arm's base is placed in it
        ET.SubElement(robot, "link", name=names[0])
    ngeoms = 0
    for b in bodies:
        nj = int(model.body_jntnum[b])
        j = int(model.body_jntadr[b]) if nj else -1
        offsets[b] = np.array(model.jnt_pos[j], dtype=np.float64) if nj else np.zeros(3)
        link = ET.SubElement(robot, "link", name=names[b])
        if model.body_mass[b] > 0:
            inertial = ET.SubElement(link, "inertial")
            _origin(inertial, model.body_ipos[b] - offsets[b], model.body_iquat[b])
            ET.SubElement(inertial, "mass", value=repr(float(model.body_mass[b])))
            ixx, iyy, izz = (repr(float(v)) for v in model.body_inertia[b])
            ET.SubElement(inertial, "inertia", ixx=ixx, iyy=iyy, izz=izz, ixy="0", ixz="0", iyz="0")
        geoms = range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b])
        collides = [g for g in geoms if model.geom_contype[g] or model.geom_conaffinity[g]]
        visual = [g for g in geoms if g not in collides] or collides
        for tag, which in (("visual", visual), ("collision", collides)):
            for g in which:
                if _geom(model, g, link, offsets[b], folder, tag):
                    ngeoms += 1
                else:
                    ignored["planes and height fields"] = (
                        ignored.get("planes and height fields", 0) + 1
                    )
        parent = int(model.body_parentid[b])
        rot = _mat(model.body_quat[b])
        xyz = np.asarray(model.body_pos[b]) - offsets[parent] + rot @ offsets[b]
        if nj:
            jname = _name(model, obj.mjOBJ_JOINT, j, f"joint{j}")
            hinge = int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
            kind = "revolute" if model.jnt_limited[j] else "continuous"
            kind = kind if hinge else "prismatic"
            if not hinge and not model.jnt_limited[j]:
                raise MjcfError(f"{where}: slide joint {jname!r} has no range")
        else:
            jname, kind = f"{names[b]}_fixed", "fixed"
        if b == root:  # the base, at the world's origin: the URDF's root link
            continue
        joint = ET.SubElement(robot, "joint", name=jname, type=kind)
        _origin(joint, xyz, model.body_quat[b])
        ET.SubElement(joint, "parent", link=names[parent])
        ET.SubElement(joint, "child", link=names[b])
        if nj:
            ET.SubElement(joint, "axis", xyz=_f(model.jnt_axis[j]))
            limit = {}
            if model.jnt_limited[j]:
                limit = {
                    "lower": repr(float(model.jnt_range[j, 0])),
                    "upper": repr(float(model.jnt_range[j, 1])),
                }
            effort = _effort(model, j)  # 0: none given (the loader's default and warning)
            limit |= {"effort": repr(effort or 0.0), "velocity": repr(MJCF_VELOCITY)}
            ET.SubElement(joint, "limit", attrib=limit)
    for kind, count in (
        ("tendons", model.ntendon),
        ("equality constraints", model.neq),
        ("sites", model.nsite),
        ("cameras", model.ncam),
        ("lights", model.nlight),
    ):
        if count:
            ignored[kind] = int(count)
    report = {
        "file": str(path),
        "bodies": len(bodies),
        "geoms": ngeoms,
        "ignored": ignored,
        "velocity": MJCF_VELOCITY,
    }
    return ET.tostring(robot, encoding="unicode"), report


def mjcf_urdf(path: str | Path, where: str | None = None) -> tuple[Path, dict]:
    """``(URDF file, report)`` of the MJCF file at ``path``: :func:`mjcf_to_urdf` written once to
    ``<cache>/mjcf/<hash of the file and MuJoCo's version>/<stem>.urdf`` (atomically)."""
    import mujoco

    path = Path(path)
    digest = hashlib.sha1(path.read_bytes() + mujoco.__version__.encode()).hexdigest()[:20]
    folder = cache_dir() / "mjcf" / digest
    folder.mkdir(parents=True, exist_ok=True)
    text, report = mjcf_to_urdf(path, folder, where)
    out = folder / f"{path.stem}.urdf"
    if not out.is_file() or out.read_text() != text:
        tmp = out.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(text)
        os.replace(tmp, out)
    return out, report
