"""How well the Panda's link capsules (``capsules`` of ``protorch/robots/panda.yaml``) cover
Franka Emika's own meshes of the Panda, and how they were fitted.

``python benchmarks/panda_volumes.py --meshes DIR`` with ``DIR`` a checkout of
``frankaemika/franka_description`` (its ``meshes/robot_arms/fer`` collision STLs and visual
COLLADA files; the meshes are not part of protorch): per link, the fraction of the visual mesh's
vertices inside the link's capsules, the fraction of points sampled on the collision mesh's
triangles (30 per triangle) inside, and the largest protrusion (mm) of each. The hand's row also
holds both fingers, fully open (the finger mesh placed as ``franka_description`` mounts it).

``--fit`` refits the capsules from the meshes (minutes): per link one to three capsules from
rough initial segments, their total volume minimised by Adam with a penalty on the mesh points
left outside, then every radius grown to enclose all points and rounded up to the millimetre,
the end points to half a millimetre; it prints them as (a, b, radius) per link.
"""

from __future__ import annotations

import argparse
import math
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import torch

from protorch.robots import load_robot
from protorch.robots.capsules import (
    protrusion,
)  # the coverage measure, shared with benchmarks/capsules.py

PANDA = load_robot("panda")
PANDA_CAPSULES = PANDA.capsule_list()
_FINGER = PANDA.point_masses[0].pos  # the left finger's base on the hand: (0, opening, offset)
PANDA_FINGER_OPENING, PANDA_FINGER_OFFSET = _FINGER[1], _FINGER[2]

LINKS = ["link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand"]


def stl_triangles(path: Path) -> np.ndarray:
    """A binary STL's triangles ``(n, 3, 3)``."""
    raw = path.read_bytes()
    n = struct.unpack("<I", raw[80:84])[0]
    rec = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    return np.frombuffer(raw[84 : 84 + 50 * n], dtype=rec)["v"].astype(np.float64)


def dae_vertices(path: Path) -> np.ndarray:
    """A COLLADA file's vertices ``(n, 3)``, every node's matrices applied."""
    root = ET.parse(path).getroot()
    ns = root.tag.split("}")[0] + "}"
    pos = {}
    for g in root.iter(ns + "geometry"):
        arrays = [a for a in g.iter(ns + "float_array") if "position" in (a.get("id") or "")]
        pos[g.get("id")] = np.concatenate(
            [np.array(a.text.split(), float).reshape(-1, 3) for a in arrays]
        )
    out = []

    def walk(node, mat):
        for child in node:
            tag = child.tag[len(ns) :]
            if tag == "matrix":
                mat = mat @ np.array(child.text.split(), float).reshape(4, 4)
            elif tag == "translate":
                t = np.eye(4)
                t[:3, 3] = np.array(child.text.split(), float)
                mat = mat @ t
        for child in node:
            tag = child.tag[len(ns) :]
            if tag == "instance_geometry":
                v = pos[child.get("url")[1:]]
                out.append(v @ mat[:3, :3].T + mat[:3, 3])
            elif tag == "node":
                walk(child, mat)

    for scene in root.iter(ns + "visual_scene"):
        for node in scene:
            walk(node, np.eye(4))
    return np.unique(np.concatenate(out).round(7), axis=0)


def fingers(root: Path) -> np.ndarray:
    """Both fingers' visual vertices in the hand's frame, fully open."""
    f = dae_vertices(root / "meshes/robot_arms/fer/visual/finger.dae")
    left = f + [0.0, PANDA_FINGER_OPENING, PANDA_FINGER_OFFSET]
    right = f * [-1.0, -1.0, 1.0] + [0.0, -PANDA_FINGER_OPENING, PANDA_FINGER_OFFSET]
    return np.concatenate([left, right])


def link_points(root: Path, link: str, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The link's visual vertices and points sampled on its collision triangles."""
    tri = stl_triangles(root / f"meshes/robot_arms/fer/collision/{link}.stl")
    u = rng.random((tri.shape[0], 30, 2))
    flip = u.sum(-1) > 1
    u[flip] = 1 - u[flip]
    surface = (
        tri[:, None, 0]
        + u[..., :1] * (tri[:, None, 1] - tri[:, None, 0])
        + u[..., 1:] * (tri[:, None, 2] - tri[:, None, 0])
    )
    out = {
        "visual": dae_vertices(root / f"meshes/robot_arms/fer/visual/{link}.dae"),
        "collision surface": surface.reshape(-1, 3),
    }
    if link == "hand":
        out["visual"] = np.concatenate([out["visual"], fingers(root)])
    return out


def coverage(root: Path, capsules: dict) -> None:
    rng = np.random.default_rng(0)
    print(
        f"{'link':<8}{'capsules':>9}{'visual inside':>15}{'largest out, mm':>17}"
        f"{'collision inside':>18}"
        f"{'largest out, mm':>17}"
    )
    for link in LINKS:
        pts = link_points(root, link, rng)
        row = f"{link:<8}{len(capsules[link]):>9}"
        for name in ("visual", "collision surface"):
            g = protrusion(pts[name], capsules[link])
            row += f"{float((g <= 0).mean()):>15.4f}{1e3 * max(float(g.max()), 0.0):>17.2f}"
        print(row)


def fit(points: np.ndarray, init, steps: int = 3000):
    """Capsules ``[(a, b, r)]`` enclosing ``points``, of small total volume (module docstring)."""
    p = torch.tensor(points)
    a = torch.tensor(np.array([s[0] for s in init]), requires_grad=True)
    b = torch.tensor(np.array([s[1] for s in init]), requires_grad=True)
    log_r = torch.full((len(init),), math.log(0.05), dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([a, b, log_r], lr=2e-3)
    for it in range(steps):
        d = b - a
        u = (((p[:, None] - a) * d).sum(-1) / d.square().sum(-1).clamp_min(1e-12)).clamp(0, 1)
        dist = (p[:, None] - a - u[..., None] * d).norm(dim=-1)  # (n, K)
        r = log_r.exp()
        out = (dist - r).min(1).values.clamp_min(0)
        vol = (math.pi * r**2 * d.norm(dim=-1) + 4 / 3 * math.pi * r**3).sum()
        loss = vol + (1e3 if it < steps // 2 else 1e4) * out.square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    a, b = np.round(a.detach().numpy() * 2000) / 2000, np.round(b.detach().numpy() * 2000) / 2000
    dist = np.stack(
        [protrusion(points, [(ai, bi, 0.0)]) for ai, bi in zip(a, b)], 1
    )  # (n, K) to each segment
    owner = dist.argmin(1)
    r = [
        math.ceil(1e3 * dist[owner == k, k].max()) / 1e3 if (owner == k).any() else 0.0
        for k in range(len(a))
    ]
    return [(tuple(ai), tuple(bi), ri) for ai, bi, ri in zip(a, b, r)]


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--meshes", type=Path, required=True, help="a checkout of frankaemika/franka_description"
    )
    p.add_argument("--fit", action="store_true", help="refit the capsules (minutes) and print them")
    a = p.parse_args()
    shipped = {
        link: [(c.a, c.b, c.radius) for c in PANDA_CAPSULES if c.link == f"panda_{link}"]
        for link in LINKS
    }
    print("the shipped capsules (protorch/robots/panda.yaml):")
    coverage(a.meshes, shipped)
    if a.fit:
        torch.set_num_threads(1)
        rng = np.random.default_rng(0)
        fitted = {}
        for link in LINKS:
            pts = link_points(a.meshes, link, rng)
            init = [(np.array(c[0]), np.array(c[1])) for c in shipped[link]]
            fitted[link] = fit(
                np.concatenate(
                    [
                        pts["visual"],
                        stl_triangles(
                            a.meshes / f"meshes/robot_arms/fer/collision/{link}.stl"
                        ).reshape(-1, 3),
                    ]
                ),
                init,
            )
            for ca, cb, r in fitted[link]:
                print(f'    Capsule("panda_{link}", {ca}, {cb}, {r}),')
        print("\nrefitted:")
        coverage(a.meshes, fitted)


if __name__ == "__main__":
    main()
