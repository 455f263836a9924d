"""Capsules fitted to a URDF's collision geometry: the link volumes of any arm, from its own
description.

:func:`fit_capsules` reads every ``<collision>`` of a URDF and encloses it in one or a few capsules
in its link's frame, a segment ``p0 -> p1`` and a radius (metres): the form of
:class:`~protorch.robots.Robot`'s ``capsules``, which the planner's ``collision=volume`` and the
MuJoCo scene read (``robot.capsules=auto``: :func:`protorch.robots.loader.auto_capsules`). The
result maps a link name to its list of ``(p0, p1, radius)``;
:func:`as_capsules` turns it into :class:`~protorch.robots.Capsule` records.

Each geometry is enclosed entirely (every point of it inside the union of its capsules):

* ``<sphere radius>``: one capsule of zero length, the sphere itself;
* ``<capsule radius length>`` (the URDF extension Drake and PyBullet read; the segment along the
  element's ``z``): itself;
* ``<cylinder radius length>``: one capsule along the cylinder's axis, of the least volume that
  holds the cylinder (its radius ``R >= r`` and its segment ``L - 2 sqrt(R^2 - r^2)`` long, ``R``
  minimising ``pi R^2 l + 4/3 pi R^3``);
* ``<box size>``: the same on a rectangular cross-section (the corners on the rim), along the axis
  and split into the number of side-by-side capsules (up to ``max_per_geometry``) that make the
  volume smallest, a capsule added only where it saves at least a fifth of the volume;
* ``<mesh filename scale>`` (read with ``trimesh``: ``pip install "protorch[meshes]"``): the mesh's
  vertices and points sampled on its triangles, cut along its principal axis into one to
  ``max_per_geometry`` pieces by the same rule, each piece enclosed by the capsule of least volume
  around its convex hull (the axis searched by Nelder-Mead from the piece's principal axis, the
  radius and segment for a given axis exact). A single capsule holds the whole mesh; with several,
  a triangle crossing a cut can protrude between two of them by the sampling's spacing (about a
  millimetre, measured by :func:`coverage`).

Every radius is rounded up, and every end point to 0.1 mm, so that the rounding never uncovers a
point. :func:`coverage` measures a fit as ``benchmarks/panda_volumes.py`` measures the Panda's:
points sampled on each link's collision surfaces, the fraction inside the link's capsules and the
largest protrusion (:func:`protrusion`); ``python benchmarks/capsules.py`` prints it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .description import Capsule
from .urdf import COLLISION_KINDS, CollisionGeometry, collision_geometry

__all__ = [
    "CollisionGeometry",
    "Segment",
    "collision_geometry",
    "fit_capsules",
    "fit_geometry",
    "as_capsules",
    "protrusion",
    "surface_points",
    "coverage",
    "enclosing_capsule",
]

Segment = tuple[
    tuple[float, float, float], tuple[float, float, float], float
]  # (p0, p1, radius), link frame
_STEP = 1e-4  # m: end points rounded to it, radii rounded up to it
_SAVING = 0.8  # one more capsule only where it makes the volume at most this fraction


# ----------------------------------------------------------------------------------------- fitting
def _capsule_volume(radius: float, length: float) -> float:
    return math.pi * radius**2 * length + 4.0 / 3.0 * math.pi * radius**3


def _prism_capsule(r: float, length: float) -> tuple[float, float]:
    """The least-volume capsule along the axis of a prism of length ``length`` whose cross-section
    reaches ``r`` from the axis (a cylinder of radius ``r``, a box's half diagonal): ``(R, l)``,
    radius and segment length, ``l = max(0, length - 2 sqrt(R^2 - r^2))``."""
    from scipy.optimize import minimize_scalar

    top = math.hypot(r, length / 2)  # a sphere around the whole prism

    def vol(radius):
        return _capsule_volume(radius, max(0.0, length - 2 * math.sqrt(max(radius**2 - r**2, 0.0))))

    res = minimize_scalar(vol, bounds=(r, top), method="bounded", options={"xatol": 1e-9})
    best = min((r, float(res.x), top), key=vol)
    return best, max(0.0, length - 2 * math.sqrt(max(best**2 - r**2, 0.0)))


def _box_capsules(size: Sequence[float], max_k: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Side-by-side capsules holding the box ``size`` centred at the origin (its own frame)."""
    half = np.asarray(size, dtype=np.float64) / 2
    best_by_k: dict[int, tuple[float, list]] = {}
    for axis in range(3):
        for tile in (a for a in range(3) if a != axis):
            other = 3 - axis - tile
            for k in range(1, max_k + 1):
                r = math.hypot(half[tile] / k, half[other])
                radius, length = _prism_capsule(r, 2 * half[axis])
                caps = []
                for i in range(k):
                    centre = np.zeros(3)
                    centre[tile] = -half[tile] + (2 * i + 1) * half[tile] / k
                    end = np.zeros(3)
                    end[axis] = length / 2
                    caps.append((centre - end, centre + end, radius))
                vol = k * _capsule_volume(radius, length)
                if k not in best_by_k or vol < best_by_k[k][0]:
                    best_by_k[k] = (vol, caps)
    return _fewest(best_by_k)


def _fewest(best_by_k: Mapping[int, tuple[float, list]]) -> list:
    """The fit with ``k`` pieces, ``k`` grown only while one more piece cuts the volume to at most
    :data:`_SAVING` of it."""
    k = 1
    while k + 1 in best_by_k and best_by_k[k + 1][0] <= _SAVING * best_by_k[k][0]:
        k += 1
    return best_by_k[k][1]


def enclosing_capsule(
    points: np.ndarray, axis: np.ndarray | None = None, through: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, float]:
    """The capsule of least volume whose segment lies on the line ``through + t axis`` and that
    holds every point ``(n, 3)``; without ``axis``, the line is searched (Nelder-Mead over its
    direction and offset, from the points' principal axis). Returns ``(p0, p1, radius)``."""
    from scipy.optimize import minimize

    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"points must be (n, 3) with n >= 1, got shape {pts.shape}")
    centre = pts.mean(0)

    def on_line(u, p):
        u = u / np.linalg.norm(u)
        rel = pts - p
        t = rel @ u  # (n,)
        rho = np.linalg.norm(rel - t[:, None] * u, axis=1)  # (n,)
        lo_r = float(rho.max())
        hi_r = math.hypot(lo_r, float(t.max() - t.min())) + 1e-12

        def vols(radii):  # (m,) radii -> (m,) volumes, (m,) far and (m,) near segment ends
            s = np.sqrt(np.maximum(radii[:, None] ** 2 - rho**2, 0.0))  # (m, n)
            t1, t0 = (t - s).max(1), (t + s).min(1)  # the segment's far end >= .., near end <= ..
            return (
                math.pi * radii**2 * np.maximum(t1 - t0, 0.0) + 4.0 / 3.0 * math.pi * radii**3,
                t1,
                t0,
            )

        radii = np.linspace(lo_r, hi_r, 33)
        for _ in range(3):  # a grid, then two finer ones around its best
            i = int(vols(radii)[0].argmin())
            radii = np.linspace(radii[max(i - 1, 0)], radii[min(i + 1, len(radii) - 1)], 33)
        v, far, near = vols(radii)
        i = int(v.argmin())
        vol, t1, t0, radius = float(v[i]), float(far[i]), float(near[i]), float(radii[i])
        if t1 < t0:  # a sphere will do: any centre in [t1, t0]
            t0 = t1 = 0.5 * (t0 + t1)
        return vol, p + t0 * u, p + t1 * u, radius

    if axis is not None:
        _, p0, p1, radius = on_line(
            np.asarray(axis, float), centre if through is None else np.asarray(through, float)
        )
        return p0, p1, radius
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    u0 = vt[0] if len(pts) > 1 else np.array([0.0, 0.0, 1.0])
    e1, e2 = (
        (vt[1], vt[2]) if len(pts) > 2 else (np.cross(u0, [1.0, 0, 0]), np.cross(u0, [0, 1.0, 0]))
    )
    scale = max(float(np.ptp(pts, axis=0).max()), 1e-6)

    def line(
        x,
        # tilt of the axis (2) and offset of the line (2), from the principal axis through the
        # centre
    ):
        return u0 + x[0] * e1 + x[1] * e2, centre + scale * (x[2] * e1 + x[3] * e2)

    res = minimize(
        lambda x: on_line(*line(x))[0],
        np.zeros(4),
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-12, "maxiter": 2000},
    )
    best = min((res.x, np.zeros(4)), key=lambda x: on_line(*line(x))[0])
    _, p0, p1, radius = on_line(*line(best))
    return p0, p1, radius


def _hull(points: np.ndarray) -> np.ndarray:
    """The vertices of the points' convex hull (all points where it is degenerate)."""
    from scipy.spatial import ConvexHull

    try:
        from scipy.spatial import QhullError
    except ImportError:  # scipy < 1.8
        from scipy.spatial.qhull import QhullError

    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return points


def _mesh_capsules(points: np.ndarray, max_k: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules holding ``points (n, 3)``: cut along the principal axis into ``k`` equal slabs."""
    centre = points.mean(0)
    axis = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    t = (points - centre) @ axis  # (n,)
    best_by_k = {}
    for k in range(1, max_k + 1):
        cuts = np.linspace(t.min(), t.max(), k + 1)
        piece = np.clip(np.searchsorted(cuts, t, side="right") - 1, 0, k - 1)  # (n,)
        caps = [
            enclosing_capsule(_hull(points[piece == i])) for i in range(k) if (piece == i).any()
        ]
        best_by_k[k] = (
            sum(_capsule_volume(r, float(np.linalg.norm(b - a))) for a, b, r in caps),
            caps,
        )
    return _fewest(best_by_k)


def _load_mesh(geom: CollisionGeometry):
    """The mesh of ``geom`` scaled, in its ``<collision>`` frame (``trimesh``; a clear error
    without it)."""
    try:
        import trimesh
    except ImportError:
        raise ImportError(
            f"link {geom.link!r} has a mesh collision geometry ({geom.mesh}); reading it needs "
            'trimesh: pip install "protorch[meshes]"'
        ) from None
    mesh = trimesh.load(str(geom.mesh), force="mesh")
    if len(mesh.vertices) == 0:
        raise ValueError(f"link {geom.link!r}: the mesh {geom.mesh} has no vertices")
    mesh.apply_scale(np.asarray(geom.scale))
    return mesh


def fit_geometry(
    geom: CollisionGeometry, *, max_per_geometry: int = 3, samples: int = 20000, seed: int = 0
) -> list[Segment]:
    """The capsules holding one collision geometry, in its link's frame (module docstring);
    ``samples`` points on a mesh's triangles join its vertices."""
    if geom.kind == "sphere":
        caps = [(np.zeros(3), np.zeros(3), geom.radius)]
    elif geom.kind == "capsule":
        caps = [
            (np.array([0, 0, -geom.length / 2]), np.array([0, 0, geom.length / 2]), geom.radius)
        ]
    elif geom.kind == "cylinder":
        radius, length = _prism_capsule(geom.radius, geom.length)
        caps = [(np.array([0, 0, -length / 2]), np.array([0, 0, length / 2]), radius)]
    elif geom.kind == "box":
        caps = _box_capsules(geom.size, max_per_geometry)
    elif geom.kind == "mesh":
        import trimesh

        mesh = _load_mesh(geom)
        pts = np.asarray(mesh.vertices, dtype=np.float64)
        if len(mesh.faces) and samples:
            pts = np.concatenate(
                [pts, np.asarray(trimesh.sample.sample_surface(mesh, samples, seed=seed)[0])]
            )
        caps = _mesh_capsules(pts, max_per_geometry)
    else:
        raise ValueError(
            f"unknown collision geometry kind {geom.kind!r}; expected one of {COLLISION_KINDS}"
        )
    rot, pos = geom.origin[:3, :3], geom.origin[:3, 3]
    out = []
    for a, b, r in caps:
        a, b = rot @ np.asarray(a, float) + pos, rot @ np.asarray(b, float) + pos
        ra, rb = np.round(a / _STEP) * _STEP, np.round(b / _STEP) * _STEP
        slack = max(
            np.linalg.norm(ra - a), np.linalg.norm(rb - b)
        )  # the rounded segment stays this close
        radius = math.ceil(round((r + slack) / _STEP, 6)) * _STEP
        out.append(
            (
                tuple(round(float(v), 4) for v in ra),
                tuple(round(float(v), 4) for v in rb),
                round(radius, 4),
            )
        )
    return out


def fit_capsules(
    urdf: str | Path,
    *,
    links: Sequence[str] | None = None,
    mesh_dir: str | Path | None = None,
    max_per_geometry: int = 3,
    samples: int = 20000,
    seed: int = 0,
) -> dict[str, list[Segment]]:
    """Capsules for every link with collision geometry (or only ``links``): link name -> list of
    ``(p0, p1, radius)`` in the link frame, metres (module docstring). A link named in ``links``
    that has no ``<collision>`` is refused with a clear error."""
    if int(max_per_geometry) < 1:
        raise ValueError(f"max_per_geometry must be >= 1, got {max_per_geometry}")
    geoms = collision_geometry(urdf, mesh_dir=mesh_dir)
    have = {g.link for g in geoms}
    if links is not None:
        missing = [n for n in links if n not in have]
        if missing:
            raise ValueError(
                f"link {missing[0]!r} has no <collision> geometry to fit capsules to; "
                f"the links that have some: {sorted(have)}"
            )
    out: dict[str, list[Segment]] = {}
    for g in geoms:
        if links is None or g.link in links:
            out.setdefault(g.link, []).extend(
                fit_geometry(g, max_per_geometry=max_per_geometry, samples=samples, seed=seed)
            )
    return out


def as_capsules(fit: Mapping[str, Sequence[Segment]]) -> tuple[Capsule, ...]:
    """``{link: [(p0, p1, radius)]}`` as :class:`~protorch.robots.Capsule` records."""
    return tuple(
        Capsule(link, tuple(map(float, a)), tuple(map(float, b)), float(r))
        for link, caps in fit.items()
        for a, b, r in caps
    )


# ---------------------------------------------------------------------------------------- coverage
def protrusion(points: np.ndarray, capsules: Sequence[Segment]) -> np.ndarray:
    """How far each point ``(n, 3)`` lies outside the union of ``capsules`` ``[(a, b, r)]``
    (``<= 0``: inside): ``(n,)``."""
    points = np.asarray(points, dtype=np.float64)
    gaps = []
    for a, b, r in capsules:
        a, b = np.asarray(a, float), np.asarray(b, float)
        d = b - a
        u = np.clip(((points - a) @ d) / max(float(d @ d), 1e-12), 0, 1)
        gaps.append(np.linalg.norm(points - a - u[:, None] * d, axis=-1) - r)
    return np.min(gaps, 0)


def surface_points(geom: CollisionGeometry, count: int = 5000, seed: int = 0) -> np.ndarray:
    """``count`` points sampled uniformly on the surface of one collision geometry, in its link's
    frame ``(count, 3)`` (``trimesh``'s meshes of the primitives, 64 segments around)."""
    import trimesh

    if geom.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=4, radius=geom.radius)
    elif geom.kind == "capsule":
        mesh = trimesh.creation.capsule(height=geom.length, radius=geom.radius, count=[64, 64])
    elif geom.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=geom.radius, height=geom.length, sections=64)
    elif geom.kind == "box":
        mesh = trimesh.creation.box(extents=geom.size)
    else:
        mesh = _load_mesh(geom)
    pts = np.asarray(trimesh.sample.sample_surface(mesh, count, seed=seed)[0], dtype=np.float64)
    return pts @ geom.origin[:3, :3].T + geom.origin[:3, 3]


def coverage(
    urdf: str | Path,
    fit: Mapping[str, Sequence[Segment]],
    *,
    mesh_dir: str | Path | None = None,
    count: int = 5000,
    seed: int = 1,
) -> dict[str, dict[str, float]]:
    """How well ``fit`` covers the URDF's collision geometry, per link (the Panda's measure,
    ``benchmarks/panda_volumes.py``): ``count`` points sampled on each collision surface (another
    seed than the fit's), ``inside`` the fraction of them inside the link's capsules and
    ``largest_out`` the largest protrusion (m); ``capsules`` the link's number of capsules."""
    per_link: dict[str, list[np.ndarray]] = {}
    for i, g in enumerate(collision_geometry(urdf, mesh_dir=mesh_dir)):
        per_link.setdefault(g.link, []).append(surface_points(g, count, seed + i))
    out = {}
    for link, pts in per_link.items():
        if link not in fit or not fit[link]:
            raise ValueError(
                f"the fit has no capsule for link {link!r}, which has collision geometry"
            )
        gap = protrusion(np.concatenate(pts), fit[link])
        out[link] = {
            "capsules": len(fit[link]),
            "inside": float((gap <= 1e-9).mean()),
            "largest_out": max(float(gap.max()), 0.0),
        }
    return out
