"""Scene nodes of the viewer: what :class:`~protorch.view.scene.SceneState` looks like in viser.

Every function takes the viser scene API (``server.scene``) and numpy arrays; none imports viser.
The point particle lives in the plane ``z = 0`` of its ``[0, 10]^2`` workspace, the arm in metres
in its base frame (table top ``z = 0``). Nodes keep their names, so drawing again replaces them.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SIDE_COLORS",
    "ArmPose",
    "draw_arm_env",
    "draw_arm_ghosts",
    "draw_arm_static",
    "draw_particle_env",
    "draw_particle_static",
    "draw_paths",
    "draw_trace",
    "draw_stroke",
    "draw_teach",
    "polylines",
    "screen_points",
    "segment_quaternion",
]

SIDE_COLORS = {"left": (31, 119, 180), "right": (230, 120, 20), None: (31, 119, 180)}
_MEAN, _START, _GOAL, _WALL = (0, 0, 0), (40, 170, 60), (210, 40, 40), (70, 70, 85)


def polylines(paths: np.ndarray) -> np.ndarray:
    """Paths ``(..., T, 3)`` -> line segments ``(n (T - 1), 2, 3)`` for ``add_line_segments``."""
    p = np.asarray(paths, dtype=np.float32).reshape(-1, *np.shape(paths)[-2:])  # (n, T, 3)
    return np.stack([p[:, :-1], p[:, 1:]], 2).reshape(-1, 2, 3)


def segment_quaternion(d: np.ndarray) -> np.ndarray:
    """The rotation ``wxyz (4,)`` taking ``+z`` onto the direction ``d (3,)``."""
    d = np.asarray(d, dtype=np.float64)
    d = d / max(np.linalg.norm(d), 1e-12)
    w = 1.0 + d[2]
    if w < 1e-9:  # d = -z: half a turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([w, -d[1], d[0], 0.0])  # cross(z, d) = (-d_y, d_x, 0)
    return q / np.linalg.norm(q)


def draw_paths(
    scene, mean: np.ndarray, samples: np.ndarray, *, width: float, color=(31, 119, 180)
) -> None:
    """The mean path ``(T, 3)`` (dark, thick) and the sample paths ``(S, T, 3)`` (thin)."""
    scene.add_line_segments("/paths/samples", polylines(samples), color, thickness=0.25 * width)
    scene.add_line_segments("/paths/mean", polylines(mean), _MEAN, thickness=width)


def draw_trace(scene, trace: np.ndarray, point: np.ndarray, *, radius: float) -> None:
    """The live controller's path so far ``(t, 3)`` and its current point ``(3,)``."""
    if len(trace) > 1:
        scene.add_line_segments(
            "/live/trace", polylines(trace), (255, 0, 200), thickness=0.6 * radius
        )
    scene.add_icosphere(
        "/live/point", radius, (255, 0, 200), position=tuple(float(v) for v in point)
    )


# ----------------------------------------------------------------------------- point particle
def draw_particle_static(scene) -> None:
    """The workspace ``[0, 10]^2``."""
    scene.add_grid(
        "/workspace",
        10.0,
        10.0,
        position=(5.0, 5.0, -0.01),
        cell_size=1.0,
        section_size=5.0,
        plane_color=(250, 250, 250),
        plane_opacity=1.0,
    )


def draw_particle_env(scene, rects: np.ndarray, start: np.ndarray, goal: np.ndarray) -> None:
    """The wall (its two rectangles ``(2, 4)`` as ``x_min, x_max, y_min, y_max``),
    start and goal."""
    for i, (x0, x1, y0, y1) in enumerate(np.asarray(rects, dtype=np.float64)):
        h = max(y1 - y0, 1e-3)
        scene.add_box(
            f"/env/wall{i}",
            _WALL,
            (x1 - x0, h, 0.4),
            position=((x0 + x1) / 2, (y0 + y1) / 2, 0.2),
            visible=bool(y1 - y0 > 1e-6),
        )
    scene.add_icosphere(
        "/env/start", 0.18, _START, position=(float(start[0]), float(start[1]), 0.0)
    )
    scene.add_icosphere("/env/goal", 0.18, _GOAL, position=(float(goal[0]), float(goal[1]), 0.0))


# ----------------------------------------------------------------------------- arm
def draw_arm_static(scene, table, start: np.ndarray) -> None:
    """The table top (``((x0, x1), (y0, y1))``, its surface at ``z = 0``) and the start point."""
    (x0, x1), (y0, y1) = table
    scene.add_box(
        "/table",
        (205, 175, 135),
        (x1 - x0, y1 - y0, 0.02),
        position=((x0 + x1) / 2, (y0 + y1) / 2, -0.011),
    )
    scene.add_box(
        "/table_to_base",
        (205, 175, 135),
        (x0 + 0.1, 0.3, 0.02),
        position=((x0 - 0.1) / 2, 0.0, -0.011),
    )
    scene.add_icosphere("/env/start", 0.012, _START, position=tuple(float(v) for v in start))


def draw_arm_env(scene, can_xy: np.ndarray, goal: np.ndarray, radius: float, height: float) -> None:
    """The can (a vertical cylinder on the table) and the target point ``(3,)``."""
    scene.add_cylinder(
        "/env/can",
        radius,
        height,
        (200, 30, 30),
        position=(float(can_xy[0]), float(can_xy[1]), height / 2),
    )
    scene.add_icosphere("/env/goal", 0.015, (30, 160, 60), position=tuple(float(v) for v in goal))


class ArmPose:
    """The arm at one configuration: a cylinder per link between consecutive frame origins
    (coincident frames skipped) and a sphere per joint. The nodes are made once; :meth:`update`
    only moves them (a pose change is then a few small property messages, not new meshes)."""

    def __init__(
        self, scene, name: str = "/arm", *, radius: float = 0.04, color=(235, 235, 240)
    ) -> None:
        self.scene, self.name, self.radius, self.color = scene, name, radius, color
        self.links: list = []
        self.joints: list = []

    def _segments(self, links: np.ndarray) -> np.ndarray:
        pts = np.asarray(links, dtype=np.float64)
        keep = [0] + [i for i in range(1, len(pts)) if np.linalg.norm(pts[i] - pts[i - 1]) > 1e-4]
        return pts[keep]

    def update(self, links: np.ndarray) -> None:
        """Move the arm to the frame origins ``links (F, 3)``."""
        pts = self._segments(links)
        n = len(pts) - 1
        while len(self.links) < n:  # first call (or a longer chain): make the nodes
            i = len(self.links)
            r = self.radius * (1.0 - 0.5 * i / max(n - 1, 1))  # thinner towards the hand
            self.links.append(self.scene.add_cylinder(f"{self.name}/link{i}", r, 1.0, self.color))
            self.joints.append(
                self.scene.add_icosphere(f"{self.name}/joint{i}", 1.1 * r, (90, 90, 100))
            )
        for i, (cyl, sph) in enumerate(zip(self.links, self.joints)):
            if i >= n:
                cyl.visible = sph.visible = False
                continue
            a, b = pts[i], pts[i + 1]
            cyl.height = float(np.linalg.norm(b - a))
            cyl.wxyz, cyl.position = segment_quaternion(b - a), tuple((a + b) / 2)
            sph.position = tuple(a)
            cyl.visible = sph.visible = True


def draw_arm_ghosts(scene, links: np.ndarray, color=(150, 150, 160)) -> None:
    """Skeletons ``(P, F, 3)`` of the arm at a few phases of the mean, as thick lines."""
    segs = np.concatenate([polylines(p) for p in np.asarray(links)], 0)
    scene.add_line_segments("/ghosts", segs, color, thickness=0.012)


# ----------------------------------------------------------------------------- teaching
_KEPT, _OK, _FLAGGED, _LIVE = (120, 120, 130), (30, 150, 60), (220, 40, 40), (255, 0, 200)


def draw_teach(scene, kept: list, pending: np.ndarray | None, ok: bool, *, width: float) -> None:
    """The teach page's paths: this environment's kept demonstrations ``[(T, 3)]`` (grey) and
    the one on show ``(T, 3)`` resampled (a line with a dot per time step; green if its checks
    pass, red if not)."""
    segs = (
        np.concatenate([polylines(k) for k in kept], 0) if kept else np.zeros((1, 2, 3), np.float32)
    )
    scene.add_line_segments("/teach/kept", segs, _KEPT, thickness=0.5 * width, visible=bool(kept))
    color = _OK if ok else _FLAGGED
    show = pending is not None and len(pending) > 1
    path = np.asarray(pending if show else np.zeros((2, 3)), dtype=np.float32)
    scene.add_line_segments("/teach/shown", polylines(path), color, thickness=width, visible=show)
    scene.add_point_cloud(
        "/teach/steps", path, color, point_size=1.5 * width, point_shape="circle", visible=show
    )


def draw_stroke(scene, stroke: np.ndarray | None, *, width: float) -> None:
    """The stroke being recorded ``(n, 3)`` (magenta; hidden for ``None`` or one point)."""
    on = stroke is not None and len(stroke) > 1
    trace = np.asarray(stroke if on else np.zeros((2, 3)), dtype=np.float32)
    scene.add_line_segments(
        "/teach/live", polylines(trace), _LIVE, thickness=0.7 * width, visible=on
    )


def screen_points(position, wxyz, fov: float, aspect: float, points) -> np.ndarray:
    """Where world points ``(n, 3)`` appear on a client's canvas: ``(n, 2)`` in ``[0, 1]^2``
    from the top left (viser's OpenCV screen convention), for the camera at ``position`` with
    orientation ``wxyz`` (camera to world, OpenCV axes: x right, y down, z forward), vertical
    field of view ``fov`` (radians) and width / height ``aspect``."""
    w, x, y, z = (float(v) for v in wxyz)
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    cam = (
        np.asarray(points, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    ) @ rot  # (n, 3)
    f = 0.5 / np.tan(0.5 * float(fov))
    return np.stack(
        [0.5 + f / float(aspect) * cam[:, 0] / cam[:, 2], 0.5 + f * cam[:, 1] / cam[:, 2]], 1
    )
