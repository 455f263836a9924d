"""Robot descriptions read as they come (protorch.robots.clean, .meshes, .layout): each fault of a
published URDF reproduced in a small file written here, and what protorch makes of it."""

from __future__ import annotations

import logging
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch

from protorch.robots import RobotError, load_robot
from protorch.robots.clean import clean_urdf
from protorch.robots.meshes import mujoco_mesh, needs_conversion, resolve_mesh

from .user_arm import user_arm_home, user_arm_urdf

HOME = user_arm_home()
TRANSMISSION = (
    '<transmission name="t2"><type>transmission_interface/SimpleTransmission</type>'
    '<joint name="elbow"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>'
    "<actuator "
    'name="m2"><mechanicalReduction>reduction</mechanicalReduction></actuator></transmission>'
    '<gazebo reference="forearm"><material>Gazebo/White</material></gazebo>'
)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PROTORCH_CACHE", str(tmp_path / "cache"))


def _arm(tmp_path, text: str, name: str = "arm.urdf", **settings):
    path = tmp_path / name
    path.write_text(text)
    return load_robot({"urdf": str(path), "end_link": "tool0", "home": HOME, **settings})


def _with(text: str, extra: str) -> str:
    return text.replace("</robot>", extra + "</robot>")


def test_declaration_and_unused_tags_are_dropped_once(tmp_path, caplog):
    text = user_arm_urdf().replace(
        '<?xml version="1.0"?>', '<?xml version="1.0" encoding="utf-8"?>'
    )
    with caplog.at_level(logging.INFO, logger="protorch.robots.clean"):
        robot = _arm(tmp_path, _with(text, TRANSMISSION))
    assert robot.found["ignored"] == {"<transmission>": 1, "<gazebo>": 1}
    lines = [r for r in caplog.records if "ignored" in r.getMessage()]
    assert len(lines) == 1 and "<transmission> x1" in lines[0].getMessage()
    plain = _arm(tmp_path, user_arm_urdf(), "plain.urdf")
    q = torch.tensor(HOME, dtype=torch.float64)
    assert torch.equal(robot.kinematics().frames(q), plain.kinematics().frames(q))
    assert plain.found == {
        "forearm_link": "wrist_1_link"
    }  # a clean file: nothing changed, its own text
    assert plain.urdf_text == (tmp_path / "plain.urdf").read_text()


def _stl(path, size=0.1):
    trimesh = pytest.importorskip("trimesh")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(trimesh.creation.box((size, size, size)).export(file_type="stl"))
    return path


def test_package_paths_one_resolver(tmp_path, monkeypatch):
    mesh = _stl(tmp_path / "ws" / "my_pkg" / "meshes" / "m.stl")
    (tmp_path / "ws" / "my_pkg" / "urdf").mkdir()
    # beside the URDF: a folder above it named my_pkg
    assert (
        resolve_mesh("package://my_pkg/meshes/m.stl", tmp_path / "ws" / "my_pkg" / "urdf") == mesh
    )
    # a folder above it holding my_pkg (a ROS workspace)
    assert resolve_mesh("package://my_pkg/meshes/m.stl", tmp_path / "ws") == mesh
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    with pytest.raises(
        FileNotFoundError, match=r"link 'x'.*'package://my_pkg/meshes/m\.stl'.*robot\.packages"
    ):
        resolve_mesh("package://my_pkg/meshes/m.stl", elsewhere, what="link 'x'")
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent:{tmp_path / 'ws'}")
    assert resolve_mesh("package://my_pkg/meshes/m.stl", elsewhere) == mesh
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    assert resolve_mesh("package://my_pkg/meshes/m.stl", elsewhere, [tmp_path / "ws"]) == mesh
    assert (
        resolve_mesh("package://my_pkg/meshes/m.stl", elsewhere, [tmp_path / "ws" / "my_pkg"])
        == mesh
    )
    assert resolve_mesh("meshes/m.stl", tmp_path / "ws" / "my_pkg") == mesh
    # the robot's readers take the same resolution: the capsule fit and the cleaned text (MuJoCo)
    text = user_arm_urdf(visual="package://my_pkg/meshes/m.stl")
    robot = _arm(tmp_path, text, packages=[str(tmp_path / "ws")])
    assert f'filename="{mesh}"' in robot.urdf_text


def _two_object_obj(path):
    """Two unit-ish tetrahedra as two objects of one OBJ (what MuJoCo reads only the first of)."""
    lines = []
    for k, dx in enumerate((0.0, 0.3)):
        lines.append(f"o part{k}")
        for v in ((0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)):
            lines.append(f"v {v[0] + dx} {v[1]} {v[2]}")
        b = 4 * k + 1
        lines += [
            f"f {b} {b + 2} {b + 1}",
            f"f {b} {b + 1} {b + 3}",
            f"f {b} {b + 3} {b + 2}",
            f"f {b + 1} {b + 2} {b + 3}",
        ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_multi_object_obj_is_merged_for_mujoco(tmp_path):
    pytest.importorskip("trimesh")
    mujoco = pytest.importorskip("mujoco")
    src = _two_object_obj(tmp_path / "two.obj")
    assert needs_conversion(src)
    out, converted = mujoco_mesh(src)
    assert converted and out.suffix == ".stl" and out.parent == tmp_path / "cache" / "meshes"
    assert mujoco_mesh(src) == (out, True)  # converted once: the same cached file
    model = mujoco.MjModel.from_xml_string(
        f'<mujoco><asset><mesh name="m" file="{out}"/></asset><worldbody>'
        '<geom type="mesh" mesh="m"/></worldbody></mujoco>'
    )
    assert (
        int(model.mesh_facenum[0]) == 8
    )  # both objects' faces (the OBJ itself: the first object's 4)
    single = tmp_path / "one.obj"
    single.write_text("\n".join(src.read_text().splitlines()[:9]) + "\n")
    assert not needs_conversion(single) and mujoco_mesh(single) == (single, False)


def test_collada_is_converted(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("collada")
    dae = tmp_path / "box.dae"
    dae.write_bytes(trimesh.creation.box((0.1, 0.2, 0.3)).export(file_type="dae"))
    out, converted = mujoco_mesh(dae)
    back = trimesh.load(str(out), force="mesh")
    assert converted and np.allclose(back.extents, (0.1, 0.2, 0.3))


def test_an_unreadable_mesh_is_refused_naming_the_link(tmp_path):
    (tmp_path / "bad.obj").write_text("o a\nv 0 0 0\no b\nthis is not an obj\n")
    with pytest.raises(
        RobotError, match=r"arm\.urdf: link 'forearm' <mesh> 1.*bad\.obj has no triangles"
    ):
        _arm(tmp_path, user_arm_urdf(visual="bad.obj"))


FINGERS = (
    '<link name="finger_l"><inertial><mass value="0.02"/><inertia ixx="1e-6" ixy="0" ixz="0" '
    'iyy="1e-6" '
    'iyz="0" izz="1e-6"/></inertial></link>'
    '<joint name="finger_joint" type="prismatic"><parent link="wrist_3_link"/><child '
    'link="finger_l"/>'
    '<origin xyz="0 0 0.05"/><axis xyz="0 1 0"/><limit lower="0" upper="0.04" effort="20" '
    'velocity="0.2"/>'
    '<mimic joint="wrist_3"/></joint>'
)


def test_joints_off_the_chain_are_locked(tmp_path):
    robot = _arm(tmp_path, _with(user_arm_urdf(), FINGERS), locked={"finger_joint": 0.03})
    assert robot.found["locked"] == {"finger_joint": 0.03} and robot.num_joints == 6
    joint = next(
        j for j in ET.fromstring(robot.urdf_text).iter("joint") if j.get("name") == "finger_joint"
    )
    assert joint.get("type") == "fixed"
    assert [float(v) for v in joint.find("origin").get("xyz").split()] == pytest.approx(
        [0.0, 0.03, 0.05]
    )
    with pytest.raises(RobotError, match=r"robot\.locked names 'elbow', a joint of the chain"):
        _arm(tmp_path, _with(user_arm_urdf(), FINGERS), locked={"elbow": 0.1})
    mujoco = pytest.importorskip("mujoco")
    from protorch.sim.scene import build_scene
    from protorch.tasks import ArmReachTask

    task = ArmReachTask(
        robot=robot,
        collision="volume",
        can_box=((0.5, 0.6), (-0.1, 0.1)),
        goal_box=((0.66, 0.7), (-0.1, 0.1)),
        table=((0.2, 0.9), (-0.5, 0.5)),
        can_radius=0.0375,
        can_height=0.23,
        reach=(0.3, 0.8),
    )
    scene = build_scene(task)  # the finger a body of its own, no degree of freedom
    assert scene.model.nv == 6 and scene.model.body("finger_l").id > 0
    assert isinstance(mujoco.MjData(scene.model), object)


def test_continuous_joints_get_limits(tmp_path):
    text = user_arm_urdf()
    i = text.index('<joint name="wrist_3"')
    j = text.index("</joint>", i)
    joint = text[i:j].replace('type="revolute"', 'type="continuous"')
    joint = joint[: joint.index("<limit")] + '<limit effort="30" velocity="2.0"/>'
    text = text[:i] + joint + text[j:]
    robot = _arm(tmp_path, text)
    assert (robot.lower[-1], robot.upper[-1]) == (-math.pi, math.pi)
    assert robot.found["continuous"] == {"wrist_3": [-math.pi, math.pi]}
    assert _arm(tmp_path, text, "b.urdf", limits={"wrist_3": [-1.0, 2.0]}).upper[-1] == 2.0


def _set_inertia(text: str, link: str, inertia: str, mass: str | None = None) -> str:
    i = text.index(f'<link name="{link}">')
    a = text.index("<inertia ", i)
    b = text.index("/>", a) + 2
    text = text[:a] + f"<inertia {inertia}/>" + text[b:]
    if mass is not None:
        a = text.index("<mass ", i)
        b = text.index("/>", a) + 2
        text = text[:a] + f'<mass value="{mass}"/>' + text[b:]
    return text


def test_inertias_are_balanced_or_refused(tmp_path, caplog):
    text = _set_inertia(
        user_arm_urdf(), "forearm", 'ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.03"'
    )
    with caplog.at_level(logging.WARNING, logger="protorch.robots.clean"):
        robot = _arm(tmp_path, text)
    assert robot.found["balanced"] == ["forearm"]
    assert any("balanced" in r.getMessage() and "forearm" in r.getMessage() for r in caplog.records)
    xx, yy, zz, xy, xz, yz = robot.inertials["forearm"].inertia
    assert (xx, yy, zz) == pytest.approx((0.05 / 3,) * 3) and (xy, xz, yz) == (
        0.0,
        0.0,
        0.0,
    )  # same trace
    with pytest.raises(RobotError, match=r"link 'forearm' has an inertia .* violate A \+ B >= C"):
        _arm(tmp_path, text, "b.urdf", balance_inertia=False)


def test_an_implausible_inertia_is_replaced_by_its_geometry(tmp_path):
    """pybullet's Panda gives every link 0.1 kg m^2: no body of a link's size has it (the bound
    mass * d^2); replaced by the solid hull of its geometry, here a box: m (b^2 + c^2) / 12."""
    text = user_arm_urdf()
    text = text.replace(
        '<link name="tool0"/>',
        '<link name="tool0"><collision><geometry><box size="0.04 0.06 0.1"/>'
        '</geometry></collision><inertial><mass value="0.1"/><inertia ixx="0.1" ixy="0" ixz="0" '
        'iyy="0.1" iyz="0" izz="0.1"/></inertial></link>',
    )
    cleaned = clean_urdf(_write(tmp_path, text), "tool0")
    assert "tool0" in cleaned.report["implausible"]
    el = next(
        link for link in ET.fromstring(cleaned.text).iter("link") if link.get("name") == "tool0"
    )
    got = [float(el.find("inertial/inertia").get(k)) for k in ("ixx", "iyy", "izz")]
    a, b, c = 0.04, 0.06, 0.1
    assert got == pytest.approx(
        [0.1 * (b * b + c * c) / 12, 0.1 * (a * a + c * c) / 12, 0.1 * (a * a + b * b) / 12]
    )


def _write(tmp_path, text, name="arm.urdf"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_missing_or_implausible_limits_are_defaulted_with_a_warning(tmp_path, caplog):
    text = user_arm_urdf().replace('velocity="2.0" effort="150"', 'velocity="10"', 1)
    with caplog.at_level(logging.WARNING, logger="protorch.robots.loader"):
        robot = _arm(tmp_path, text)
    assert (
        robot.max_velocity[0] == 2.0
        and robot.max_torque[0] == 50.0
        and robot.max_torque[1] == 150.0
    )
    assert robot.found["max_velocity_default"] == {"joints": ["shoulder_pan"], "value": 2.0}
    # the defaults reach every reader of the URDF text (the controllers read the kinematics')
    assert robot.kinematics().max_velocity.tolist() == list(robot.max_velocity)
    limit = ET.fromstring(robot.urdf_text).find("joint[@name='shoulder_pan']/limit")
    assert float(limit.get("velocity")) == 2.0 and float(limit.get("effort")) == 50.0
    assert robot.found["max_torque_default"] == {"joints": ["shoulder_pan"], "value": 50.0}
    assert sum("shoulder_pan" in r.getMessage() for r in caplog.records) == 2


def test_end_link_found_or_the_candidates_listed(tmp_path):
    path = _write(tmp_path, user_arm_urdf())
    assert load_robot({"urdf": str(path), "home": HOME}).end_link == "tool0"
    two = _write(
        tmp_path,
        _with(
            user_arm_urdf(),
            FINGERS.replace("finger_l", "finger_a")
            + FINGERS.replace("finger_l", "finger_b").replace("finger_joint", "finger_joint_b"),
        ),
        "two.urdf",
    )
    with pytest.raises(
        RobotError,
        match=r"robot\.end_link is not set and .* 2 leaf links reached through 7 moving "
        r"joints: \['finger_a', 'finger_b'\]",
    ):
        load_robot({"urdf": str(two), "home": HOME})


@pytest.mark.slow
def test_home_and_workspace_found_for_a_custom_arm(tmp_path):
    """No home, no workspace: the hand-down IK finds both, reported; a shipped robot keeps the
    Panda's."""
    from protorch.tasks import ArmReachTask

    robot = load_robot({"urdf": str(_write(tmp_path, user_arm_urdf()))})
    home = robot.found["home"]
    assert home["residual"] < 1e-6 and robot.home == tuple(home["pose"])
    kin = robot.kinematics()
    pose = kin.ee_pose(torch.tensor(robot.home, dtype=torch.float64))
    assert pose[:3, 3].tolist() == pytest.approx(
        home["target"], abs=1e-4
    )  # the target rounded to 0.1 mm
    assert float(pose[2, 2]) == pytest.approx(-1.0, abs=1e-6)  # the hand's z pointing down
    task = ArmReachTask(robot=robot, collision="volume")
    layout = robot.found["layout"]
    assert (
        task.can_box == tuple(map(tuple, layout["can_box"]))
        and task.can_radius == layout["can_radius"]
    )
    r0, r1 = layout["reach"]
    assert r0 < home["target"][0] < task.can_box[0][0] < task.goal_box[0][1] <= r1
    panda = ArmReachTask(robot="panda")
    assert (panda.can_box, panda.goal_box, panda.table, panda.can_radius, panda.can_height) == (
        ((0.50, 0.62), (-0.12, 0.12)),
        ((0.66, 0.74), (-0.24, 0.24)),
        ((0.2, 0.9), (-0.5, 0.5)),
        0.0375,
        0.23,
    )


@pytest.mark.slow
def test_an_arm_that_cannot_hold_its_hand_down_is_refused(tmp_path):
    text = re.sub(
        r'lower="[^"]*" upper="[^"]*"', 'lower="-0.05" upper="0.05"', user_arm_urdf(scale=0.2)
    )  # upright
    with pytest.raises(RobotError, match=r"holds its hand down .* over no interval of 10 cm"):
        load_robot({"urdf": str(_write(tmp_path, text))})


@pytest.mark.slow
def test_pybullet_arms_run_unedited():
    """pybullet's own files (skipped without `pip install "protorch[arms]"`): the faults of the
    issue, each found, and MuJoCo's scene of each arm with the chain's joints its only ones."""
    pybullet_data = pytest.importorskip("pybullet_data")
    pytest.importorskip("mujoco")
    from protorch.sim.scene import build_scene
    from protorch.tasks import ArmReachTask

    root = pybullet_data.getDataPath()
    xarm = load_robot({"urdf": f"{root}/xarm/xarm6_robot.urdf"})
    assert xarm.end_link == "link6" and xarm.found["ignored"] == {
        "<gazebo>": 8,
        "<transmission>": 6,
    }
    assert xarm.found["balanced"] == ["link2", "link3"] and len(xarm.found["converted"]) == 6
    panda = load_robot({"urdf": f"{root}/franka_panda/panda.urdf", "end_link": "panda_grasptarget"})
    assert panda.found["locked"] == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    assert "panda_hand" in panda.found["implausible"]
    for robot in (xarm, panda):
        scene = build_scene(ArmReachTask(robot=robot, collision="volume"))
        assert scene.model.nv == robot.num_joints
        assert robot.found["home"]["residual"] < 1e-6


@pytest.mark.slow
def test_a_half_size_arm_finds_its_home_from_a_perturbed_seed(tmp_path):
    """The example arm at half size: from the limits' middle (the arm upright, singular) its hand
    reaches down over less than 10 cm; a perturbed seed finds the home, reported as used."""
    robot = load_robot({"urdf": str(_write(tmp_path, user_arm_urdf(scale=0.5)))})
    home, layout = robot.found["home"], robot.found["layout"]
    assert home["seed"].startswith("perturbed seed") and home["residual"] < 1e-6
    assert layout["reach"][1] - layout["reach"][0] >= 0.10
    pose = robot.kinematics().ee_pose(torch.tensor(robot.home, dtype=torch.float64))
    assert float(pose[2, 2]) == pytest.approx(-1.0, abs=1e-6)  # the hand pointing down
