"""The KUKA LBR iiwa 14 shipped with protorch (protorch/robots/iiwa14.urdf, iiwa14.yaml): KUKA's
published dimensions and limits, physical inertials, its home pose (gripper down, 10 cm above the
table in front), its fitted capsules covering its collision geometry, and MuJoCo's frames equal
to protorch's kinematics."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import protorch.robots
from protorch.robots.capsules import fit_capsules
from protorch.robots.kinematics import ArmKinematics

ROBOTS = Path(protorch.robots.__file__).resolve().parent
URDF = ROBOTS / "iiwa14.urdf"
DESC = yaml.safe_load((ROBOTS / "iiwa14.yaml").read_text())
F64 = torch.float64


@pytest.fixture(scope="module")
def kin():
    return ArmKinematics(URDF, end_link=DESC["end_link"])


def test_the_chain_has_kukas_dimensions(kin):
    assert kin.num_joints == 7 and kin.joint_names == [f"iiwa_joint_{i}" for i in range(1, 8)]
    pos = kin.link_positions(torch.zeros(7, dtype=F64))  # (F, 3): straight up at q = 0
    assert torch.allclose(pos[:, :2], torch.zeros_like(pos[:, :2]), atol=1e-6)
    height = dict(zip(kin.frame_names, pos[:, 2].tolist()))
    # KUKA's data sheet: shoulder (joint 2) 0.36 m, elbow (joint 4) +0.42, wrist (joint 6) +0.40,
    # flange +0.126
    assert height["iiwa_link_2"] == pytest.approx(0.36, abs=1e-6)
    assert height["iiwa_link_4"] == pytest.approx(0.78, abs=1e-6)
    assert height["iiwa_link_6"] == pytest.approx(1.18, abs=1e-6)
    assert height["iiwa_link_ee"] == pytest.approx(1.306, abs=1e-6)
    assert height["iiwa_tcp"] == pytest.approx(1.426, abs=1e-6)


def test_limits_torques_and_speeds_are_kukas():
    joints = [j for j in ET.parse(URDF).getroot().iter("joint") if j.get("type") == "revolute"]
    lim = [j.find("limit") for j in joints]
    deg = [math.degrees(float(x.get("upper"))) for x in lim]
    assert deg == pytest.approx([170, 120, 170, 120, 170, 120, 175], abs=1e-9)
    assert [float(x.get("lower")) for x in lim] == [-float(x.get("upper")) for x in lim]
    assert [float(x.get("effort")) for x in lim] == [320, 320, 176, 176, 110, 40, 40]
    assert [math.degrees(float(x.get("velocity"))) for x in lim] == pytest.approx(
        [85, 85, 100, 75, 130, 135, 135]
    )
    assert len(DESC["max_acceleration"]) == 7 and min(DESC["max_acceleration"]) > 0


def test_inertials_are_physical():
    total = 0.0
    for link in ET.parse(URDF).getroot().iter("link"):
        el = link.find("inertial")
        if el is None:
            continue
        i = {
            k: float(el.find("inertia").get(k)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
        }
        mat = np.array(
            [
                [i["ixx"], i["ixy"], i["ixz"]],
                [i["ixy"], i["iyy"], i["iyz"]],
                [i["ixz"], i["iyz"], i["izz"]],
            ]
        )
        eig = np.linalg.eigvalsh(mat)
        assert eig[0] > 0 and eig[0] + eig[1] >= eig[2], link.get(
            "name"
        )  # a rigid body's principal moments
        total += float(el.find("mass").get("value"))
    assert total == pytest.approx(31.41)  # 30.61 kg of arm (Drake's) and the 0.8 kg gripper


def test_home_holds_the_gripper_down_10_cm_above_the_table_in_front(kin):
    q = torch.tensor(DESC["home"], dtype=F64)
    assert bool(kin.within_limits(q))
    pose = kin.ee_pose(q)
    assert torch.allclose(pose[:3, 3], torch.tensor([0.50, 0.0, 0.10], dtype=F64), atol=5e-4)
    assert float(pose[:3, 2] @ torch.tensor([0.0, 0.0, -1.0], dtype=F64)) > 1 - 1e-6
    # joint 4 (the elbow) keeps a margin to its 120 degree stop
    assert math.degrees(2.0944 - abs(float(q[3]))) > 10


def test_the_fitted_capsules_ride_on_the_chain_and_clear_the_table_at_home(kin):
    from protorch.robots import capsule_segments
    from protorch.robots.capsules import as_capsules

    caps = as_capsules(fit_capsules(URDF))
    assert {c.link for c in caps} == set(kin.frame_names) - {"iiwa_tcp"}
    frames = kin.frames(torch.tensor(DESC["home"], dtype=F64))
    a, b, r = capsule_segments(frames, kin.frame_names, caps)
    moving = torch.tensor([c.link != "iiwa_link_0" for c in caps])
    low = torch.minimum(a[:, 2], b[:, 2]) - r  # (C,) the lowest point of each capsule
    assert bool((low[moving] > 0).all())


def test_the_fit_covers_the_iiwas_collision_geometry():
    pytest.importorskip("trimesh")
    from protorch.robots.capsules import coverage

    cov = coverage(URDF, fit_capsules(URDF), count=3000)
    assert len(cov) == 9
    assert all(row["inside"] == 1.0 and row["largest_out"] == 0.0 for row in cov.values())


def test_the_mujoco_scene_has_the_same_frames_inertials_and_motors(kin, gen):
    pytest.importorskip("mujoco")
    import mujoco

    from protorch.sim.scene import ARM_BITS, build_scene
    from protorch.tasks import ArmReachTask

    task = ArmReachTask(
        robot="iiwa14",
        collision="volume",
        can_box=((0.60, 0.70), (-0.12, 0.12)),
        goal_box=((0.74, 0.78), (-0.16, 0.16)),
    )
    scene = build_scene(task)
    model, data = scene.model, mujoco.MjData(scene.model)
    assert model.nv == 7 and float(model.body("iiwa_link_2").mass[0]) == pytest.approx(6.35)
    assert scene.torque_limits.tolist() == [320, 320, 176, 176, 110, 40, 40]
    # the colliding geometry is the fitted capsules alone (the URDF's cylinders and boxes inside
    # them)
    arm = [
        g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name.startswith("iiwa")
    ]
    colliding = [g for g in arm if model.geom_contype[g] or model.geom_conaffinity[g]]
    assert len(colliding) == len(task.robot.capsule_list()) == 12
    assert all(model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE for g in colliding)
    assert all((model.geom_contype[g], model.geom_conaffinity[g]) == ARM_BITS for g in colliding)
    q = kin.lower + (kin.upper - kin.lower) * torch.rand(16, 7, generator=gen, dtype=F64)  # (16, 7)
    frames = kin.frames(q)  # (16, F, 4, 4)
    for i in range(16):
        data.qpos[:] = q[i].numpy()
        mujoco.mj_kinematics(model, data)
        for k, name in enumerate(kin.frame_names):
            body = model.body(name).id
            assert np.allclose(data.xpos[body], frames[i, k, :3, 3].numpy(), atol=1e-6)
            assert np.allclose(
                data.xmat[body].reshape(3, 3), frames[i, k, :3, :3].numpy(), atol=1e-6
            )
    # at home, the can in its box: no contact with the can or the table
    data.qpos[:] = task.robot.home
    data.mocap_pos[scene.can_mocap] = [0.65, 0.0, task.can_height / 2]
    mujoco.mj_forward(model, data)
    assert data.sensordata[scene.can_contact] == 0 and data.sensordata[scene.table_contact] == 0


@pytest.mark.slow
def test_a_tiny_run_of_the_iiwa_goes_end_to_end_through_mujoco(tmp_path):
    """``experiment=arm_reach robot=iiwa14``: demonstrations, loop, kinematic tests and MuJoCo, the
    iiwa's joints in the episodes file, its workspace in the environments, and every success at
    its target by protorch's own kinematics of the recorded joints."""
    pytest.importorskip("mujoco", minversion="4.0")
    from protorch.experiments import run_experiment
    from tests.experiments.test_arm_reach import cfg

    m = run_experiment(
        cfg("robot=iiwa14", "task.collision=volume", "settings.baselines=[]"), tmp_path
    )
    assert (
        m["robot"]["name"] == "KUKA LBR iiwa 14"
        and m["robot"]["joints"] == 7
        and m["robot"]["capsules"] == 12
    )
    for section in ("test", "dynamic"):
        assert (
            0 <= m["physics"][section]["success_rate"] <= 1
            and m["physics"][section]["failures"]["diverged"] == 0
        )
    with np.load(tmp_path / m["physics"]["episodes_file"]) as f:
        q, can, target = f["q"], f["can"], f["target"]
    assert (
        q.shape[-1] == 7
        and q.shape[0] == m["physics"]["test"]["episodes"] + m["physics"]["dynamic"]["episodes"]
    )
    held_out = m["physics"]["test"]["episodes"]
    # the held-out environments lie in the iiwa's workspace (conf/robot/iiwa14.yaml), not the
    # Panda's
    assert (can[:held_out, 0, 0] >= 0.60 - 1e-9).all() and (
        target[:held_out, 0, 0] >= 0.74 - 1e-9
    ).all()
    # every MuJoCo success ends with the gripper's tool centre point (protorch's kinematics of the
    # recorded joints) at the target (benchmarks/replay_physics.py re-derives the Panda's frames
    # only)
    with np.load(tmp_path / m["physics"]["episodes_file"]) as f:
        success = f["success"]
    kin = ArmKinematics(URDF, end_link=DESC["end_link"])
    tcp = kin.ee_position(torch.from_numpy(q[:, -1]).to(F64)).numpy()  # (E, 3)
    gap = np.linalg.norm(tcp[:, :2] - target[:, -1], axis=-1)  # (E,)
    assert success.any() and (gap[success] <= 0.02 + 1e-3).all()
