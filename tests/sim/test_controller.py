"""The computed-torque controller (protorch.sim.controller): its torques are MuJoCo's inverse
dynamics, its mass matrix MuJoCo's, and gains the timestep cannot integrate are refused."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from protorch.robots import PANDA_LIMITS
from protorch.sim.controller import ComputedTorque, check_gains, dense_mass
from protorch.sim.scene import controller_model


@pytest.mark.parametrize("mass_scale", [1.0, 1.3])
def test_torques_are_mj_inverse_of_the_commanded_acceleration(task, rng, mass_scale):
    model = controller_model(task, mass_scale=mass_scale)
    lo, hi = np.array(PANDA_LIMITS).T
    n = 6
    q = lo + (hi - lo) * rng.random((n, 7))
    qd, q_r, v_r, a_r = (rng.normal(size=(n, 7)) for _ in range(4))
    ctrl = ComputedTorque(model, n, kp=400.0, kd=40.0)
    tau = ctrl.torques(q, qd, torch.from_numpy(q_r), torch.from_numpy(v_r), torch.from_numpy(a_r)).numpy()
    data = mujoco.MjData(model)
    for i in range(n):
        data.qpos[:], data.qvel[:] = q[i], qd[i]
        data.qacc[:] = a_r[i] + 400.0 * (q_r[i] - q[i]) + 40.0 * (v_r[i] - qd[i])
        mujoco.mj_inverse(model, data)
        assert np.allclose(tau[i], data.qfrc_inverse, rtol=1e-10, atol=1e-9)


def test_dense_mass_is_mujocos_full_matrix(task, rng):
    model = controller_model(task)
    data = mujoco.MjData(model)
    data.qpos[:] = rng.normal(size=7)
    mujoco.mj_forward(model, data)
    full = np.zeros((7, 7))
    mujoco.mj_fullM(model, data, full)
    assert np.allclose(dense_mass(model, data.M[None])[0], full, atol=1e-14)


def test_gains_the_timestep_cannot_integrate_are_refused(task):
    assert check_gains(400.0, 40.0, 0.002) == (400.0, 40.0)
    with pytest.raises(ValueError, match=r"kp dt\^2 / mass \+ 2 kd dt / mass < 4"):
        check_gains(400.0, 1000.0, 0.002)
    with pytest.raises(ValueError, match="physics.kp must be > 0"):
        check_gains(0.0, 40.0, 0.002)
    model = controller_model(task, timestep=0.01)
    with pytest.raises(ValueError, match="unstable"):
        ComputedTorque(model, 3, kp=400.0, kd=200.0)
