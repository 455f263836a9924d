"""Capsules fitted to a URDF's collision geometry (protorch.robots.capsules): every fit holds the
geometry it was fitted to (points sampled on its surface, with another seed than the fit's), the
analytic fits are the least volume, and bad geometry is refused by name."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protorch.robots.capsules import (
    as_capsules,
    collision_geometry,
    coverage,
    enclosing_capsule,
    fit_capsules,
    protrusion,
    surface_points,
)

trimesh = pytest.importorskip("trimesh")

# a tilted, offset element: the transform matters
ORIGIN = '<origin xyz="0.05 -0.1 0.2" rpy="0.4 -0.3 1.1"/>'
PRIMITIVES = {
    "sphere": '<sphere radius="0.06"/>',
    "capsule": '<capsule radius="0.04" length="0.22"/>',
    "cylinder": '<cylinder radius="0.05" length="0.3"/>',
    "short cylinder": '<cylinder radius="0.1" length="0.04"/>',
    "box": '<box size="0.3 0.12 0.05"/>',
    "cube": '<box size="0.08 0.08 0.08"/>',
}


def urdf_with(geometry: str, origin: str = ORIGIN) -> str:
    return (
        f'<robot name="t"><link name="base"/><link name="body"><collision>{origin}<geometry>'
        f"{geometry}"
        f'</geometry></collision></link><joint name="j" type="revolute"><parent link="base"/>'
        f'<child link="body"/><axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint></robot>'
    )


@pytest.fixture(scope="module")
def mesh_dir(tmp_path_factory):
    """An L-shaped mesh (a cylinder with a box across its top, two bodies), written as STL under a
    ROS package's layout."""
    root = tmp_path_factory.mktemp("pkg")
    (root / "meshes").mkdir()
    bar = trimesh.creation.box(
        extents=[0.2, 0.06, 0.05],
        transform=trimesh.transformations.translation_matrix([0.1, 0.0, 0.15]),
    )
    trimesh.util.concatenate(
        [trimesh.creation.cylinder(radius=0.04, height=0.3, sections=32), bar]
    ).export(root / "meshes" / "l.stl")
    return root


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_a_primitive_is_inside_its_capsules(name):
    urdf = urdf_with(PRIMITIVES[name])
    fit = fit_capsules(urdf)
    assert list(fit) == ["body"] and 1 <= len(fit["body"]) <= 3
    (geom,) = collision_geometry(urdf)
    pts = surface_points(geom, 4000, seed=7)  # (4000, 3) in the link frame
    # enclosed exactly (the radii are rounded up): no sampled point outside, beyond round-off
    assert float(protrusion(pts, fit["body"]).max()) <= 1e-9
    # and tight: some surface point touches the capsules' boundary within 2 mm
    assert float(protrusion(pts, fit["body"]).max()) >= -2e-3


def test_a_mesh_is_inside_its_capsules_to_a_millimetre(mesh_dir):
    urdf = urdf_with('<mesh filename="package://pkg/meshes/l.stl" scale="1.5 1.5 1.5"/>')
    fit = fit_capsules(urdf, mesh_dir=mesh_dir)
    assert 1 <= len(fit["body"]) <= 3
    cov = coverage(urdf, fit, mesh_dir=mesh_dir, count=20000, seed=11)["body"]
    # points on the mesh's triangles (other samples than the fit's): inside, or at most 1 mm out
    # where a triangle crosses the cut between two capsules
    assert cov["inside"] >= 0.995 and cov["largest_out"] <= 1e-3
    # the mesh's own vertices, scaled and placed by <origin>, are all inside
    (geom,) = collision_geometry(urdf, mesh_dir=mesh_dir)
    verts = (
        trimesh.load(mesh_dir / "meshes" / "l.stl").vertices * 1.5 @ geom.origin[:3, :3].T
        + geom.origin[:3, 3]
    )
    assert float(protrusion(verts, fit["body"]).max()) <= 1e-9


def test_the_analytic_cylinder_capsule_is_the_least_volume_enclosing_one():
    r, length = 0.05, 0.3
    fit = fit_capsules(
        urdf_with(f'<cylinder radius="{r}" length="{length}"/>', '<origin xyz="0 0 0"/>')
    )
    ((a, b, radius),) = fit["body"]
    vol = math.pi * radius**2 * math.dist(a, b) + 4 / 3 * math.pi * radius**3
    # brute force over the radius: a capsule of radius R on the axis holds the rims iff its segment
    # reaches L/2 - sqrt(R^2 - r^2) either way
    grid = np.linspace(r, math.hypot(r, length / 2), 200001)
    seg = np.maximum(length - 2 * np.sqrt(grid**2 - r**2), 0.0)
    best = float((math.pi * grid**2 * seg + 4 / 3 * math.pi * grid**3).min())
    assert vol == pytest.approx(best, rel=5e-3) and vol >= best * (1 - 1e-9)
    # the free search (axis not given) on the cylinder's rims finds no smaller one
    theta = np.linspace(0, 2 * math.pi, 720, endpoint=False)
    rims = np.concatenate(
        [
            np.stack([r * np.cos(theta), r * np.sin(theta), np.full_like(theta, z)], 1)
            for z in (-length / 2, length / 2)
        ]
    )
    p0, p1, rad = enclosing_capsule(rims)
    assert float(protrusion(rims, [(p0, p1, rad)]).max()) <= 1e-9
    assert math.pi * rad**2 * np.linalg.norm(p1 - p0) + 4 / 3 * math.pi * rad**3 >= best * (
        1 - 1e-6
    )


def test_several_collisions_of_a_link_add_up_and_become_capsule_records():
    urdf = (
        '<robot name="t"><link name="a"><collision><geometry><sphere '
        'radius="0.03"/></geometry></collision>'
        '<collision><origin xyz="0 0 0.2"/><geometry><cylinder radius="0.02" '
        'length="0.1"/></geometry>'
        "</collision></link></robot>"
    )
    fit = fit_capsules(urdf)
    assert len(fit["a"]) == 2
    cov = coverage(urdf, fit, count=2000)
    assert cov["a"]["inside"] == 1.0 and cov["a"]["capsules"] == 2
    caps = as_capsules(fit)
    assert [c.link for c in caps] == ["a", "a"] and caps[0].a == caps[0].b == (0.0, 0.0, 0.0)
    assert caps[0].radius == pytest.approx(0.03)


def test_bad_geometry_is_refused_by_name(tmp_path):
    with pytest.raises(FileNotFoundError, match="link 'body'.*'missing.stl'"):
        fit_capsules(urdf_with('<mesh filename="missing.stl"/>'))
    with pytest.raises(ValueError, match="link 'body'.*positive radius"):
        fit_capsules(urdf_with('<cylinder radius="-0.1" length="0.2"/>'))
    with pytest.raises(ValueError, match="<box size> must be 3 numbers"):
        fit_capsules(urdf_with('<box size="0.1 0.2"/>'))
    with pytest.raises(ValueError, match="link 'base' has no <collision>"):
        fit_capsules(urdf_with(PRIMITIVES["sphere"]), links=["base"])
    with pytest.raises(ValueError, match="not a URDF"):
        fit_capsules("<mujoco/>")


def test_robot_capsules_auto_is_this_fit_and_refuses_an_unreadable_mesh(tmp_path, mesh_dir):
    from protorch.robots import RobotError, load_robot

    robot = load_robot("iiwa14")  # capsules: auto
    urdf = robot.urdf
    fit = fit_capsules(urdf)
    assert {k: [(c.a, c.b, c.radius) for c in v] for k, v in robot.capsules.items()} == fit
    # a mesh in place of link 7's cylinder: fitted from the mesh, beside the URDF
    text = urdf.read_text().replace(
        '<cylinder radius="0.05" length="0.07"/>', '<mesh filename="meshes/l.stl"/>'
    )
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "l.stl").write_bytes((mesh_dir / "meshes" / "l.stl").read_bytes())
    (tmp_path / "arm.urdf").write_text(text)
    settings = {
        "urdf": str(tmp_path / "arm.urdf"),
        "end_link": "iiwa_tcp",
        "home": list(robot.home),
    }
    mine = load_robot(settings)
    assert mine.capsules["iiwa_link_6"] == robot.capsules["iiwa_link_6"]
    cov = coverage(
        tmp_path / "arm.urdf",
        {k: [(c.a, c.b, c.radius) for c in v] for k, v in mine.capsules.items()},
        count=4000,
    )
    assert cov["iiwa_link_7"]["inside"] >= 0.995 and cov["iiwa_link_7"]["largest_out"] <= 1e-3
    (tmp_path / "meshes" / "l.stl").unlink()
    (tmp_path / "arm2.urdf").write_text(text)  # another file: not the cached fit
    with pytest.raises(
        RobotError, match="arm2.urdf: link 'iiwa_link_7' <mesh> 1 names the mesh 'meshes/l.stl'"
    ):
        load_robot({**settings, "urdf": str(tmp_path / "arm2.urdf")})
