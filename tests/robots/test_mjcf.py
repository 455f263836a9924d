"""An arm in MuJoCo's format (``robot.mjcf=PATH``, protorch.robots.mjcf): written once as a URDF
with MuJoCo's kinematics (to 1e-9, checked against MuJoCo itself), its geoms, joints' limits
and inertias; the shipped iiwa written to MJCF by MuJoCo reads back as the URDF it came from;
bad files refused in one line before any work."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch

from protorch.robots import RobotError, load_robot
from protorch.robots.clean import urdf_chain
from protorch.robots.urdf import rpy_matrix

mujoco = pytest.importorskip("mujoco")

ARM = """<mujoco model="mj_arm">
  <compiler angle="radian"/>
  <asset><mesh name="tip" vertex="0 0 0  0.05 0 0  0 0.05 0  0 0 0.05"/></asset>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body name="base">
      <geom type="cylinder" size="0.08 0.05" pos="0 0 0.05"/>
      <body name="shoulder" pos="0 0 0.1">
        <joint name="j1" axis="0 0 1" range="-3.1 3.1"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.2" size="0.06"/>
        <body name="upper" pos="0 0 0.2" euler="0 0 0.3">
          <joint name="j2" axis="0 1 0" pos="0 0 0.01" range="-2 2"/>
          <geom type="capsule" fromto="0 0 0 0 0 0.45" size="0.05"/>
          <body name="fore" pos="0 0 0.45" quat="0.99 0.1 0.05 0">
            <joint name="j3" axis="0 1 0" range="-2.8 2.8"/>
            <geom type="box" size="0.04 0.04 0.2" pos="0 0 0.2"/>
            <body name="w1" pos="0 0 0.4">
              <joint name="j4" axis="0 0 1"/>
              <geom type="sphere" size="0.045"/>
              <body name="w2">
                <joint name="j5" axis="0 1 0" range="-2 2"/>
                <geom type="mesh" mesh="tip"/>
                <body name="w3" pos="0 0 0.1">
                  <joint name="j6" axis="0.6 0 0.8" range="-3 3"/>
                  <geom type="cylinder" size="0.04 0.02" pos="0 0 0.02"
                        contype="0" conaffinity="0"/>
                  <body name="tool" pos="0 0 0.06"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
    <body name="can" pos="0.5 0 0.1"><freejoint/><geom type="cylinder" size="0.03 0.1"/></body>
  </worldbody>
  <actuator>
    <motor joint="j1" gear="100" ctrlrange="-1 1"/>
    <position joint="j2" forcerange="-50 50"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PROTORCH_CACHE", str(tmp_path / "cache"))


def urdf_fk(text: str, end_link: str, q) -> np.ndarray:
    """The end link's pose (4, 4) from a URDF's text in float64 (pytorch_kinematics parses the
    file's numbers in float32, 1e-7 off)."""
    out, i = np.eye(4), 0
    for j in urdf_chain(ET.fromstring(text), end_link):
        o, step = j.find("origin"), np.eye(4)
        if o is not None:
            step[:3, :3] = rpy_matrix([float(v) for v in o.get("rpy", "0 0 0").split()])
            step[:3, 3] = [float(v) for v in o.get("xyz", "0 0 0").split()]
        out = out @ step
        if j.get("type") != "fixed":
            a = np.array([float(v) for v in j.find("axis").get("xyz").split()])
            a /= np.linalg.norm(a)
            k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            rot = np.eye(4)
            rot[:3, :3] = np.eye(3) + np.sin(q[i]) * k + (1 - np.cos(q[i])) * k @ k
            out, i = out @ rot, i + 1
    return out


def mujoco_fk(model, names, end_link: str, q) -> np.ndarray:
    """The end body's pose (4, 4) by MuJoCo at joint values ``q`` of joints ``names``."""
    data = mujoco.MjData(model)
    for name, v in zip(names, q):
        data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)]] = v
    mujoco.mj_kinematics(model, data)
    b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, end_link)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
    return out


def _write(tmp_path, text: str, name: str = "arm.xml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_an_mjcf_arm_is_read_as_mujoco_reads_it(tmp_path):
    path = _write(tmp_path, ARM)
    robot = load_robot({"mjcf": str(path), "home": [0.0, 0.5, 1.0, 0.0, 0.5, 0.0]})
    assert robot.name == "mj_arm" and robot.end_link == "tool"  # the leaf: the can is left out
    assert robot.joint_names == ("j1", "j2", "j3", "j4", "j5", "j6")
    found = robot.found["mjcf"]
    assert found["bodies"] == 8 and found["ignored"]["free bodies"] == 1
    assert robot.found["continuous"] == {"j4": [-np.pi, np.pi]}  # j4 has no range
    assert robot.max_torque[:2] == (100.0, 50.0)  # the motor's gear x ctrlrange, the forcerange
    assert robot.found["max_torque_default"]["joints"] == ["j3", "j4", "j5", "j6"]
    model = mujoco.MjModel.from_xml_path(str(path))
    rng = np.random.default_rng(0)
    kin = robot.kinematics()
    for _ in range(10):
        q = rng.uniform(robot.lower, robot.upper)
        want = mujoco_fk(model, robot.joint_names, "tool", q)
        assert np.abs(urdf_fk(robot.urdf_text, "tool", q) - want).max() < 1e-9
        got = kin.ee_pose(torch.tensor(q, dtype=torch.float64)).numpy()
        assert np.abs(got - want).max() < 1e-5  # pytorch_kinematics' float32 parse
    caps = {c.link: c for c in robot.capsule_list()}
    assert caps["upper"].radius == pytest.approx(0.05, abs=1e-9)  # a capsule geom: exact
    assert set(caps) >= {"shoulder", "upper", "fore", "w1", "w2"}  # w3's geom only visual
    for link, mass in (("upper", model.body_mass[3]), ("w1", model.body_mass[5])):
        assert robot.inertials[link].mass == pytest.approx(float(mass), rel=1e-12)


def test_an_mjcf_arm_builds_its_mujoco_scene(tmp_path):
    from protorch.sim.scene import build_scene
    from protorch.tasks import ArmReachTask

    robot = load_robot({"mjcf": str(_write(tmp_path, ARM)), "home": [0.0, 0.5, 1.0, 0.0, 0.5, 0.0]})
    scene = build_scene(ArmReachTask(robot=robot, collision="volume"))
    assert scene.model.nv == 6  # the chain's joints only: the free can is not in the scene
    names = {mujoco.mj_id2name(scene.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(20)}
    assert {"shoulder", "upper", "fore", "w1", "w2", "w3", "tool"} <= names


def test_the_iiwa_through_mujocos_mjcf_is_the_urdfs_arm(tmp_path):
    """The shipped iiwa's URDF compiled by MuJoCo and saved as MJCF (mj_saveLastXML) reads back
    with the URDF's kinematics to 1e-9, its joint limits and torque limits."""
    iiwa = load_robot("iiwa14")
    text = iiwa.urdf_text
    head = text.index(">", text.index("<robot")) + 1
    keep = '<mujoco><compiler fusestatic="false" discardvisual="false"/></mujoco>'
    mujoco.MjModel.from_xml_string(text[:head] + keep + text[head:])
    path = tmp_path / "iiwa14.xml"
    mujoco.mj_saveLastXML(
        str(path), mujoco.MjModel.from_xml_string(text[:head] + keep + text[head:])
    )
    robot = load_robot({"mjcf": str(path), "end_link": iiwa.end_link, "home": list(iiwa.home)})
    assert robot.joint_names == iiwa.joint_names and robot.max_torque == iiwa.max_torque
    assert np.allclose(robot.lower, iiwa.lower, atol=1e-9)
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.uniform(iiwa.lower, iiwa.upper)
        a, b = urdf_fk(robot.urdf_text, iiwa.end_link, q), urdf_fk(text, iiwa.end_link, q)
        assert np.abs(a - b).max() < 1e-9


@pytest.mark.parametrize(
    "text, settings, message",
    [
        (None, {}, r"robot\.mjcf=.*nothing\.xml: no such file"),
        ("<mujoco><worldbody>", {}, r"robot\.mjcf=.*arm\.xml is not valid XML"),
        (
            '<mujoco><worldbody><body name="b"><joint type="hinge"/>'
            '<geom sise="0.1"/></body></worldbody></mujoco>',
            {},
            r"robot\.mjcf=.*arm\.xml: MuJoCo cannot read it: .*sise",
        ),
        (
            '<mujoco><worldbody><body name="b"><joint type="ball"/><geom size="0.1"/></body>'
            "</worldbody></mujoco>",
            {},
            r"robot\.mjcf=.*: body 'b' has a ball joint",
        ),
        (ARM, {"urdf": "arm.urdf"}, r"robot\.urdf=.*arm\.urdf and robot\.mjcf=.* are both set"),
        (ARM, {"end_link": "w9"}, r"robot\.end_link='w9' is not a link of robot\.mjcf="),
        (ARM, {"end_link": "w2"}, r"robot\.end_link='w2': the chain .* has 5 joints"),
    ],
)
def test_bad_mjcf_is_one_line_naming_the_file(tmp_path, text, settings, message):
    path = tmp_path / "nothing.xml" if text is None else _write(tmp_path, text)
    with pytest.raises(RobotError, match=message) as exc:
        load_robot({"mjcf": str(path), "home": [0.0] * 6, **settings})
    assert "\n" not in str(exc.value)
