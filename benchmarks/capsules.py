"""Capsules fitted to a URDF's collision geometry (``protorch.robots.capsules``): the fit, its
coverage per link and its time.

``python benchmarks/capsules.py [URDF] [--mesh-dir DIR] [--count N]`` (default: the KUKA LBR iiwa 14
shipped with protorch) fits the capsules and prints, per link with collision geometry, the number
of capsules, the fraction of ``N`` points sampled on each of the link's collision surfaces that
lie inside the link's capsules, the largest protrusion (mm), and the capsules' volume against the
geometry's own (primitives; meshes: their convex hull's): the measure
``benchmarks/panda_volumes.py``
reports for the Panda. ``--print`` writes the capsules in ``robot.capsules``' yaml form.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from _timing import Stopwatch

from protorch.robots.capsules import collision_geometry, coverage, fit_capsules

IIWA14 = Path(__file__).resolve().parents[1] / "protorch" / "robots" / "iiwa14.urdf"


def geometry_volume(g) -> float:
    if g.kind == "sphere":
        return 4 / 3 * math.pi * g.radius**3
    if g.kind == "capsule":
        return math.pi * g.radius**2 * g.length + 4 / 3 * math.pi * g.radius**3
    if g.kind == "cylinder":
        return math.pi * g.radius**2 * g.length
    if g.kind == "box":
        return float(np.prod(g.size))
    from protorch.robots.capsules import _load_mesh

    return float(_load_mesh(g).convex_hull.volume)


def capsule_volume(caps) -> float:
    return sum(math.pi * r**2 * math.dist(a, b) + 4 / 3 * math.pi * r**3 for a, b, r in caps)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("urdf", nargs="?", type=Path, default=IIWA14)
    p.add_argument("--mesh-dir", type=Path, default=None, help="where package:// mesh paths live")
    p.add_argument("--count", type=int, default=20000, help="points sampled per collision surface")
    p.add_argument(
        "--print", action="store_true", help="print the capsules in robot.capsules' yaml form"
    )
    a = p.parse_args()
    with Stopwatch() as sw:
        fit = fit_capsules(a.urdf, mesh_dir=a.mesh_dir)
    fit_s = sw.wall
    cov = coverage(a.urdf, fit, mesh_dir=a.mesh_dir, count=a.count)
    geoms: dict[str, list] = {}
    for g in collision_geometry(a.urdf, mesh_dir=a.mesh_dir):
        geoms.setdefault(g.link, []).append(g)
    print(
        f"{a.urdf}: capsules fitted in {fit_s:.2f} s; {a.count} points sampled per collision "
        "surface\n"
    )
    print(
        "| link | geometry | capsules | surface points inside | largest protrusion | capsule "
        "volume / geometry volume |"
    )
    print("|---|---|---|---|---|---|")
    for link, row in cov.items():
        kinds = ", ".join(g.kind for g in geoms[link])
        ratio = capsule_volume(fit[link]) / sum(geometry_volume(g) for g in geoms[link])
        print(
            f"| {link} | {kinds} | {row['capsules']} | {row['inside']:.4f} | "
            f"{1e3 * row['largest_out']:.1f} mm "
            f"| {ratio:.2f} |"
        )
    if a.print:
        print("\ncapsules:")
        for link, caps in fit.items():
            print(f"  {link}:")
            for c0, c1, r in caps:
                print(f"    - {{a: {list(c0)}, b: {list(c1)}, radius: {r}}}")


if __name__ == "__main__":
    main()
