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
    assert sorted(float(m.geom_size[g, 0]) for g in caps) == sorted(c.radius for c in robot.capsule_list())
    assert np.allclose(m.actuator_forcerange, np.stack([-scene.torque_limits, scene.torque_limits], 1))
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
