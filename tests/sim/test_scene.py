"""The MuJoCo scene (protorch.sim.scene): the project's URDF with the published inertials, the link
capsules, the torque motors, and MuJoCo's contact reports for the can and the table."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from protorch.robots import load_robot
from protorch.sim.scene import build_scene, controller_model


@pytest.fixture(scope="module")
def scene(task):
    return build_scene(task)


def test_frames_match_protorch_kinematics(scene, task, gen):
    lo, hi = task.kinematics.lower, task.kinematics.upper
    q = lo + (hi - lo) * torch.rand(8, 7, generator=gen, dtype=torch.float64)
    frames = task.kinematics.frames(q).numpy()  # (8, F, 4, 4)
    data = mujoco.MjData(scene.model)
    for i in range(8):
        data.qpos[:] = q[i].numpy()
        mujoco.mj_forward(scene.model, data)
        for f, name in enumerate(task.kinematics.frame_names):
            body = data.body(name)
            assert np.abs(body.xpos - frames[i, f, :3, 3]).max() < 1e-6, name
            assert np.abs(body.xmat.reshape(3, 3) - frames[i, f, :3, :3]).max() < 1e-6, name


def test_inertials_capsules_motors_and_joints(scene):
    m, robot = scene.model, load_robot("panda")
    inertials = robot.inertials  # the URDF's <inertial>
    assert set(inertials) == {f"panda_link{i}" for i in range(8)} | {"panda_hand"}
    for name, inertial in inertials.items():
        assert m.body(name).mass[0] == pytest.approx(inertial.mass), name
        assert np.allclose(m.body(name).ipos, inertial.com), name
    caps = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
    assert len(caps) == len(robot.capsule_list())
    assert sorted(float(m.geom_size[g, 0]) for g in caps) == sorted(
        c.radius for c in robot.capsule_list()
    )
    assert np.allclose(
        m.actuator_forcerange, np.stack([-scene.torque_limits, scene.torque_limits], 1)
    )
    assert np.allclose(m.jnt_range, np.stack([robot.lower, robot.upper], 1))
    assert np.allclose(scene.torque_limits, robot.max_torque)  # the URDF's effort
    assert np.allclose(m.dof_damping, robot.damping) and np.allclose(m.dof_armature, robot.armature)
    heavy = controller_model(scene.task, mass_scale=2.0)
    assert heavy.body("panda_link3").mass[0] == pytest.approx(2 * inertials["panda_link3"].mass)
    assert heavy.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT


def _contacts(scene, q, can_xy):
    data = mujoco.MjData(scene.model)
    data.qpos[:] = q
    data.mocap_pos[scene.can_mocap] = (*can_xy, scene.task.can_height / 2)
    mujoco.mj_forward(scene.model, data)
    return data.sensordata[scene.can_contact], data.sensordata[scene.table_contact], data.ncon


def test_contact_sensors_report_the_can_and_the_table(scene, task):
    q0 = task.start_config().numpy()
    tcp = task.kinematics.ee_position(torch.from_numpy(q0)).numpy()
    can, table, ncon = _contacts(scene, q0, tcp[:2])  # the can where the hand is
    assert can >= 1 and table == 0 and ncon >= 1
    can, table, ncon = _contacts(scene, q0, (tcp[0] + 0.3, 0.3))  # the can far away
    assert can == 0 and table == 0 and ncon == 0
    low = q0.copy()
    low[1] += 0.35  # lean forward: the hand goes through the table top
    can, table, _ = _contacts(scene, low, (0.85, 0.45))
    assert task.kinematics.ee_position(torch.from_numpy(low))[2] < 0 and table >= 1 and can == 0


def test_a_users_arm_gets_its_urdfs_inertials_motors_and_visual_mesh(tmp_path):
    from protorch.sim.scene import CAPSULE_GROUP, VISUAL_GROUP
    from protorch.tasks.arm.reach import ArmReachTask
    from tests.robots.user_arm import user_arm_home, user_arm_urdf

    mesh = (
        tmp_path / "my_arm_description" / "meshes" / "forearm.obj"
    )  # a ROS-like package beside the URDF
    mesh.parent.mkdir(parents=True)
    mesh.write_text(
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.4\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"
    )
    urdf = tmp_path / "my_arm_description" / "urdf" / "my_arm.urdf"
    urdf.parent.mkdir()
    urdf.write_text(user_arm_urdf(visual="package://my_arm_description/meshes/forearm.obj"))
    task = ArmReachTask(robot={"urdf": str(urdf), "end_link": "tool0", "home": user_arm_home()})
    scene = build_scene(task)
    m, robot = scene.model, task.robot
    for name, inertial in robot.inertials.items():  # the URDF's own <inertial>
        assert m.body(name).mass[0] == pytest.approx(inertial.mass), name
    assert np.allclose(scene.torque_limits, [150, 150, 150, 30, 30, 30])  # <limit effort>
    meshes = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(meshes) == 1 and m.geom_group[meshes[0]] == VISUAL_GROUP and scene.visuals
    arm = [g for g in range(m.ngeom) if m.geom_contype[g] == 1]  # what collides: the capsules only
    assert len(arm) == len(robot.capsule_list()) and all(
        m.geom_group[g] == CAPSULE_GROUP for g in arm
    )
    assert m.body("tool0").mass[0] == 0.0  # the URDF's geometry adds no mass
    data = mujoco.MjData(m)
    data.qpos[:] = task.start_q
    for _ in range(100):  # gravity compensated: the arm holds its home (no self-contact)
        mujoco.mj_forward(m, data)
        data.ctrl[:] = data.qfrc_bias
        mujoco.mj_step(m, data)
    assert np.abs(data.qpos - np.array(task.start_q)).max() < 1e-3 and data.ncon == 0
