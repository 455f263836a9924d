"""The computed-torque controller (protorch.sim.controller): its torques are MuJoCo's inverse
dynamics, its mass matrix MuJoCo's, and gains the timestep cannot integrate are refused."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from protorch.robots import load_robot

PANDA_LIMITS = tuple(zip(load_robot("panda").lower, load_robot("panda").upper))
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
    tau = ctrl.torques(
        q, qd, torch.from_numpy(q_r), torch.from_numpy(v_r), torch.from_numpy(a_r)
    ).numpy()
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


def test_feasible_torques_scale_only_the_reference_acceleration_and_keep_within_the_bound(
    task, rng
):
    """``feasible_torques``: the torque of ``s a_r`` with the largest ``s`` in [0, 1] that keeps
    every
    joint within the bound; ``s = 1`` (the plain torques) where the command is already within it."""
    model = controller_model(task)
    lo, hi = np.array(PANDA_LIMITS).T
    n = 40
    q = lo + (hi - lo) * rng.random((n, 7))
    qd, q_r, v_r = (0.1 * rng.normal(size=(n, 7)) for _ in range(3))
    q_r = q + 0.001 * q_r
    a_r = (
        rng.normal(size=(n, 7)) * np.where(np.arange(n) % 2 == 0, 1.0, 60.0)[:, None]
    )  # half of them far too fast
    ctrl = ComputedTorque(model, n, kp=400.0, kd=40.0)
    args = [torch.from_numpy(x) for x in (q_r, v_r, a_r)]
    bound = torch.tensor([87.0] * 4 + [12.0] * 3) * 0.9
    plain = ctrl.torques(q, qd, *args)
    tau, a_s = ctrl.feasible_torques(q, qd, *args, bound)
    s = (a_s / args[2]).numpy()  # (n, 7) the same scale on every joint of an episode
    assert np.allclose(s, s[:, :1], rtol=1e-9) and ((s >= 0) & (s <= 1 + 1e-12)).all()
    assert torch.allclose(tau, ctrl.torques(q, qd, args[0], args[1], a_s), rtol=1e-10, atol=1e-9)
    within = (plain.abs() <= bound).all(-1)  # (n,)
    assert within.any() and (~within).any()
    assert np.allclose(s[within.numpy()], 1.0) and torch.allclose(
        tau[within], plain[within], rtol=1e-12, atol=1e-9
    )
    feedback_ok = (
        ctrl.torques(q, qd, args[0], args[1], torch.zeros_like(args[2])).abs() <= bound
    ).all(-1)
    assert (tau[feedback_ok].abs() <= bound * (1 + 1e-9)).all()  # feasible wherever s = 0 is
    scaled = feedback_ok & ~within
    assert scaled.sum() >= 5
    # the largest such s: a touch more acceleration passes the bound on some joint
    more = torch.from_numpy(np.minimum(s[scaled.numpy()] * 1.001 + 1e-6, 1.0)) * args[2][scaled]
    ctrl_small = ComputedTorque(model, int(scaled.sum()), kp=400.0, kd=40.0)
    over = ctrl_small.torques(
        q[scaled.numpy()], qd[scaled.numpy()], args[0][scaled], args[1][scaled], more
    )
    assert ((over.abs() > bound).any(-1)).all()
