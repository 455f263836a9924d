"""Robot descriptions (protorch.robots.load_robot): the Panda's from its yaml and URDF, a user's
arm from settings, the capsules fitted to its collision cylinders, the URDF's inertials, and one
line naming the setting for every bad input."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import pytest
import torch

from protorch.robots import Robot, RobotError, check_inertials, load_robot, shipped_robots
from protorch.robots.loader import urdf_inertials
from tests.robots.user_arm import user_arm_home, user_arm_urdf, write_user_arm


@pytest.fixture()
def arm(tmp_path):
    return {"urdf": str(write_user_arm(tmp_path)), "end_link": "tool0", "home": user_arm_home()}


def test_the_panda_reads_its_urdf_and_yaml():
    panda = load_robot()
    assert "panda" in shipped_robots() and panda == load_robot("panda") and panda.name == "Panda"
    assert (
        panda.num_joints == 7
        and panda.end_link == "panda_hand_tcp"
        and panda.base_links == ("panda_link0",)
    )
    root = ET.fromstring(panda.urdf_text)
    limits = [j.find("limit") for j in root.iter("joint") if j.get("type") == "revolute"]
    assert panda.max_torque == tuple(float(lim.get("effort")) for lim in limits)
    assert panda.max_velocity == tuple(float(lim.get("velocity")) for lim in limits)
    assert panda.lower == tuple(float(lim.get("lower")) for lim in limits)
    kin = panda.kinematics()
    assert bool(kin.within_limits(torch.tensor(panda.home, dtype=torch.float64)))
    assert {c.link for c in panda.capsule_list()} <= set(kin.frame_names) and len(
        panda.capsule_list()
    ) == 18
    assert load_robot(panda.settings) == panda  # the settings it was loaded from give it back


def test_a_users_arm_from_settings(arm):
    robot = load_robot(arm)
    assert isinstance(robot, Robot) and robot.name == "my_arm" and robot.num_joints == 6
    assert (
        robot.max_acceleration == (10.0,) * 6 and robot.damping == (1.0,) * 6
    )  # the stated defaults
    assert robot.max_torque == (150.0, 150.0, 150.0, 30.0, 30.0, 30.0)  # the URDF's effort
    assert (
        robot.base_links == ("base_link",) and robot.forearm_link == "wrist_1_link"
    )  # auto: what the third joint from the end moves
    check_inertials(robot)  # every moving link has its mass
    assert (
        load_robot(
            {**arm, "name": "Mine", "max_acceleration": [5.0] * 6, "capsules": "none"}
        ).capsules
        == {}
    )
    over = load_robot({**arm, "max_velocity": 1.5, "damping": [0.5] * 6})
    assert over.max_velocity == (1.5,) * 6 and over.damping == (0.5,) * 6
    assert over.kinematics().max_velocity.tolist() == [1.5] * 6  # the setting in the text


def test_auto_capsules_enclose_the_collision_cylinders(arm, gen):
    robot = load_robot(arm)
    root = ET.fromstring(robot.urdf_text)
    for link in root.iter("link"):
        col = link.find("collision")
        if col is None:
            continue
        caps = robot.capsules[link.get("name")]
        assert len(caps) == 1
        cap, shape = caps[0], col.find("geometry")[0]
        cz, r = float(col.find("origin").get("xyz").split()[2]), float(shape.get("radius"))
        half = float(shape.get("length", 0.0)) / 2
        # points on the primitive's surface (cylinder: side and caps; sphere) are inside the capsule
        u = torch.rand(2000, 3, generator=gen, dtype=torch.float64)
        ang = 2 * math.pi * u[:, 0]
        if shape.tag == "cylinder":
            rad = torch.where(u[:, 2] < 0.5, torch.full_like(u[:, 1], r), r * u[:, 1].sqrt())
            z = torch.where(
                u[:, 2] < 0.5, -half + 2 * half * u[:, 1], torch.where(u[:, 2] < 0.75, -half, half)
            )
            pts = torch.stack([rad * ang.cos(), rad * ang.sin(), cz + z], -1)
        else:
            v = torch.randn(2000, 3, generator=gen, dtype=torch.float64)
            pts = r * v / v.norm(dim=-1, keepdim=True) + torch.tensor(
                [0.0, 0.0, cz], dtype=torch.float64
            )
        a, b = torch.tensor(cap.a, dtype=torch.float64), torch.tensor(cap.b, dtype=torch.float64)
        d = b - a
        t = ((pts - a) @ d / d.dot(d).clamp_min(1e-12)).clamp(0, 1)
        dist = (pts - (a + t[:, None] * d)).norm(dim=-1)
        assert float(dist.max()) <= cap.radius + 1e-12, link.get("name")
        assert float(dist.max()) >= cap.radius - 1e-3  # tight: the surface touches the capsule


def test_inertials_with_a_rotated_frame_are_rotated_into_the_link(tmp_path):
    text = (
        '<robot name="r"><link name="a"><inertial><origin xyz="0.1 0 0" rpy="0 0 '
        '1.5707963267948966"/>'
        '<mass value="2"/><inertia ixx="1" ixy="0" ixz="0" iyy="2" iyz="0" '
        'izz="3"/></inertial></link></robot>'
    )
    inertial = urdf_inertials(ET.fromstring(text))["a"]
    assert inertial.mass == 2.0 and inertial.com == (0.1, 0.0, 0.0)
    xx, yy, zz, xy, xz, yz = inertial.inertia  # a quarter turn about z swaps the x and y moments
    assert (xx, yy, zz) == pytest.approx((2.0, 1.0, 3.0)) and (xy, xz, yz) == pytest.approx(
        (0, 0, 0), abs=1e-12
    )


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda a, p: {**a, "urdf": str(p / "nothing.urdf")},
            r"robot\.urdf=.*nothing\.urdf: no such file",
        ),
        (
            lambda a, p: {**a, "urdf": _write(p, "<robot><link name=")},
            r"robot\.urdf=.* is not valid XML",
        ),
        (lambda a, p: {**a, "urdf": _write(p, "<sdf/>")}, r"robot\.urdf=.* is not a URDF"),
        (
            lambda a, p: {**a, "end_link": "tool9"},
            r"robot\.end_link='tool9' is not a link of robot\.urdf",
        ),
        (lambda a, p: {**a, "home": [0.0] * 5}, r"robot\.home=\[.*\] must be 6 joint angles"),
        (
            lambda a, p: {**a, "home": [0.0, 0.0, 4.0, 0.0, 0.0, 0.0]},
            r"robot\.home has 4\.0 for joint 'elbow', outside",
        ),
        (
            lambda a, p: {**a, "home": [0.0, "x", 0, 0, 0, 0]},
            r"robot\.home has 'x' for joint 'shoulder_lift'",
        ),
        (
            lambda a, p: {**a, "urdf": _write(p, user_arm_urdf(fixed=("wrist_1",)))},
            r"robot\.end_link='tool0': the chain "
            r"of robot\.urdf=.* has 5 joints .*needs at least 6",
        ),
        (
            lambda a, p: {**a, "max_acceleration": [1.0] * 3},
            r"robot\.max_acceleration=\[.*\] must be a number or 6",
        ),
        (lambda a, p: {**a, "damping": -1.0}, r"robot\.damping has -1\.0 for joint 'shoulder_pan'"),
        (lambda a, p: {**a, "colour": "red"}, r"robot\.colour is not a robot setting"),
        (lambda a, p: {**a, "base": "r2d2"}, r"robot\.base='r2d2' is not a shipped robot"),
        (lambda a, p: {"home": a["home"]}, r"robot\.urdf must be set"),
        (
            lambda a, p: {
                **a,
                "capsules": {"nowhere": [{"a": [0, 0, 0], "b": [0, 0, 1], "radius": 0.1}]},
            },
            r"robot\.capsules has link 'nowhere', not on the chain",
        ),
        (
            lambda a, p: {
                **a,
                "capsules": {"forearm": [{"a": [0, 0, 0], "b": [0, 0, 1], "radius": -1}]},
            },
            r"robot\.capsules\.forearm\[0\]=.* must be",
        ),
        (
            lambda a, p: {
                **a,
                "urdf": _write(
                    p,
                    user_arm_urdf().replace(
                        '<cylinder radius="0.045" length="0.4"/>', '<mesh filename="forearm.stl"/>'
                    ),
                ),
            },
            r"robot\.urdf=.*: link 'forearm' <mesh> 1 names the mesh 'forearm\.stl', which is not "
            r"found",
        ),
        (
            lambda a, p: {**a, "forearm_link": "elbow_link"},
            r"robot\.forearm_link='elbow_link' is not a link",
        ),
    ],
)
def test_bad_input_is_one_line_naming_the_setting(arm, tmp_path, change, message):
    with pytest.raises(RobotError, match=message) as exc:
        load_robot(change(arm, tmp_path))
    assert "\n" not in str(exc.value)


def test_missing_inertials_are_refused_naming_the_link(arm, tmp_path):
    robot = load_robot(
        {**arm, "urdf": _write(tmp_path, user_arm_urdf(inertials=False))}
    )  # kinematics is fine
    with pytest.raises(
        RobotError,
        match=r"link 'shoulder' \(moved by joint 'shoulder_pan'\) has no <inertial>.*"
        r"settings\.physics\.run=never",
    ):
        check_inertials(robot)


def _write(folder, text: str) -> str:
    path = folder / f"u{abs(hash(text))}.urdf"
    path.write_text(text)
    return str(path)


def test_max_jerk_is_a_robot_setting_the_pandas_franka_published():
    """``robot.max_jerk``: the Panda's is Franka's published limit (with its velocity and
    acceleration limits, ``protorch.robots.published``), a robot without one gets 7,500 rad/s^3,
    a setting overrides it, and a bad value is one line naming the key."""
    from protorch.policy.limits import robot_limits
    from protorch.robots.loader import RobotError, load_robot
    from protorch.robots.published import FRANKA_JOINT_LIMITS

    panda = load_robot("panda")
    for key, want in FRANKA_JOINT_LIMITS.items():
        assert getattr(panda, key) == pytest.approx(want), key
    lim = robot_limits(panda, 7)
    assert lim[2].tolist() == list(FRANKA_JOINT_LIMITS["max_jerk"])
    assert load_robot("iiwa14").max_jerk == (7500.0,) * 7
    assert load_robot({"base": "panda", "max_jerk": 5000}).max_jerk == (5000.0,) * 7
    with pytest.raises(RobotError, match="robot.max_jerk"):
        load_robot({"base": "panda", "max_jerk": [1.0, 2.0]})
