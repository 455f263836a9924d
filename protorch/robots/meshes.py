"""Mesh files of a robot description: where a ``<mesh filename>`` is on disk
(:func:`resolve_mesh`, the one resolver every reader uses: the capsule fit, the MuJoCo scene,
the pictures) and a copy MuJoCo can read (:func:`mujoco_mesh`).

Resolution of ``package://NAME/REST`` (and ``file://``, relative and absolute paths):

1. beside the URDF: its folder and each folder above it, where a folder is ``NAME`` itself or
   holds a folder ``NAME`` with ``REST`` inside (a ROS workspace's layout);
2. each folder of the environment variable ``ROS_PACKAGE_PATH`` (``:``-separated), searched the
   same way;
3. each folder of ``packages`` (``robot.packages=[DIR, ...]``): ``DIR/NAME/REST``, ``DIR/REST``.

A relative path is looked up from the URDF's folder, then under ``packages``.

MuJoCo reads STL, OBJ and its own MSH, but of an OBJ with several objects only the first, and no
Collada ``.dae``: such a file is read whole with ``trimesh`` (every object merged, in the file's
own units) and written once as binary STL to a cache folder (``PROTORCH_CACHE`` or
``~/.cache/protorch``, ``meshes/<hash of the file>.stl``, written atomically).
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Sequence
from pathlib import Path

__all__ = [
    "cache_dir",
    "load_mesh",
    "mujoco_mesh",
    "needs_conversion",
    "obj_objects",
    "resolve_mesh",
]

_MUJOCO_EXTS = {".stl", ".obj", ".msh"}
_OBJECT_LINE = re.compile(rb"^[og]\s+\S", re.MULTILINE)


def cache_dir() -> Path:
    """Where converted files go: ``$PROTORCH_CACHE`` or ``~/.cache/protorch``."""
    return Path(os.environ.get("PROTORCH_CACHE") or Path.home() / ".cache" / "protorch")


def _split(filename: str) -> tuple[str | None, str]:
    """``(package name or None, the rest)`` of a mesh filename."""
    if filename.startswith("package://"):
        rest = filename[len("package://") :]
        name, _, tail = rest.partition("/")
        return name, tail
    if filename.startswith("file://"):
        return None, filename[len("file://") :]
    return None, filename


def _in_package(root: Path, name: str, rest: str) -> Path | None:
    for folder in (root, root / name):
        if folder.name == name and (folder / rest).is_file():
            return folder / rest
    return None


def resolve_mesh(
    filename: str,
    urdf_dir: str | Path | None,
    packages: Sequence[str | Path] = (),
    what: str = "a <mesh>",
) -> Path:
    """The file a URDF ``<mesh filename>`` names (module docstring), absolute; a
    ``FileNotFoundError`` of one line naming ``what``, the filename and every place looked."""
    name, rest = _split(filename or "")
    if not rest:
        raise FileNotFoundError(f"{what} has an empty filename")
    looked: list[str] = []
    packages = [Path(p).expanduser() for p in packages]
    if name is None:
        path = Path(rest)
        if path.is_absolute():
            if path.is_file():
                return path
            looked.append(str(path))
        else:
            for root in ([Path(urdf_dir)] if urdf_dir is not None else []) + packages:
                looked.append(str(root / rest))
                if (root / rest).is_file():
                    return (root / rest).resolve()
    else:
        roots: list[Path] = []
        if urdf_dir is not None:
            here = Path(urdf_dir).resolve()
            roots += [here, *here.parents]
        roots += [Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(":") if p]
        for root in roots:
            hit = _in_package(root, name, rest)
            if hit is not None:
                return hit.resolve()
        for root in packages:
            for cand in (root / name / rest, root / rest):
                if cand.is_file():
                    return cand.resolve()
        looked.append(
            f"folders named {name!r} at or above {urdf_dir}, ROS_PACKAGE_PATH, "
            f"robot.packages={[str(p) for p in packages]}"
        )
    raise FileNotFoundError(
        f"{what} names the mesh {filename!r}, which is not found (looked in "
        f"{'; '.join(looked)}); give its folder in robot.packages=[DIR]"
    )


def obj_objects(path: str | Path) -> int:
    """The number of ``o`` / ``g`` (object, group) lines of an OBJ file."""
    return len(_OBJECT_LINE.findall(Path(path).read_bytes()))


def needs_conversion(path: str | Path) -> bool:
    """Whether MuJoCo cannot read ``path`` whole: not STL / OBJ / MSH, or an OBJ of several
    objects."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in _MUJOCO_EXTS:
        return True
    return ext == ".obj" and obj_objects(path) > 1


def load_mesh(path: str | Path, what: str = "a <mesh>"):
    """The whole mesh of a file (every object of an OBJ, every geometry of a ``.dae`` scene, in
    place), as one ``trimesh.Trimesh``; a ``ValueError`` of one line naming ``what`` and the file
    for one that cannot be read or has no triangles."""
    try:
        import trimesh
    except ImportError:
        raise ImportError(
            f'{what}: reading the mesh {path} needs trimesh: pip install "protorch[meshes]"'
        ) from None
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 (trimesh's readers raise many kinds)
        raise ValueError(
            f"{what}: the mesh {path} cannot be read: {type(exc).__name__}: {exc}"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise ValueError(f"{what}: the mesh {path} has no triangles")
    return mesh


def mujoco_mesh(path: str | Path, what: str = "a <mesh>") -> tuple[Path, bool]:
    """``(file MuJoCo reads, converted)``: ``path`` itself, or its merged STL in the cache
    (converted once; the name is the hash of the file's bytes)."""
    path = Path(path)
    if not needs_conversion(path):
        return path, False
    digest = hashlib.sha1(path.read_bytes()).hexdigest()[:20]
    out = cache_dir() / "meshes" / f"{digest}.stl"
    if not out.is_file():
        mesh = load_mesh(path, what)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
        tmp.write_bytes(mesh.export(file_type="stl"))
        os.replace(tmp, out)
    return out, True
