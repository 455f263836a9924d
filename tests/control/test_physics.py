"""Physics episodes (protorch.control.physics): a reach the can does not block succeeds with the
controller tracking to a fraction of a millimetre, a can in the way is hit and named, a wrong
controller model costs tracking accuracy, and a broken mean is a named failure, never a crash."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from protorch.control.episodes import check_timing
from protorch.robots import load_robot

PANDA_MAX_ACCELERATION = load_robot("panda").max_acceleration
from protorch.control.physics import FixedMeans, run_physics_episodes, substeps
from protorch.sim.scene import build_scene, controller_model
from protorch.tasks.arm.demos import detour_paths
from tests.sim.conftest import reach, task  # noqa: F401  (MuJoCo's skip and the physics fixtures)

TIMING = check_timing(0.02, 1.5, 0.4)
GAINS = dict(kp=400.0, kd=40.0, ref_kp=10.0, max_acceleration=PANDA_MAX_ACCELERATION)


def _run(task, promp, w, envs, mass_scale=1.0):
    walk = envs[:, None].expand(-1, TIMING.total + 1, -1)
    return run_physics_episodes(
        build_scene(task),
        controller_model(task, mass_scale=mass_scale),
        FixedMeans(w),
        promp,
        TIMING,
        walk,
        **GAINS,
    )


def test_a_clear_reach_succeeds_and_a_can_in_the_way_is_hit(task, reach):
    promp, w = reach
    clear = [0.55, 0.30, 0.70, -0.10]  # the can far to the left of the straight path
    mid = task.ee_path(promp.trajectory(w))[0, 50, :2].tolist()  # the can on the path, half way
    envs = torch.tensor([clear, [*mid, 0.70, -0.10]], dtype=torch.float64)
    res = _run(task, promp, w.expand(2, -1), envs)
    assert res.success.tolist() == [True, False]
    fail = res.failures
    assert not any(v[0] for v in fail.values()) and fail["can_contact"][1]
    assert res.contact[0].sum() == 0 and res.contact[1].sum() > 0 and res.deepest[1] < 0
    assert res.tracking_rms[0] < 1e-4 and res.final_goal_distance[0] < 2e-3
    assert res.max_torque_ratio[0] < 1.0
    # the kinematic verdicts of the planned mean, under the same volumes, agree
    assert task.success(promp.trajectory(w.expand(2, -1)), envs).tolist() == [True, False]
    s = res.summary(kinematic=np.array([True, False]))
    assert s["agreement"] == 1.0 and s["can_contacts"] == 1 and s["failures"]["can_contact"] == 1


def test_a_wrong_controller_model_tracks_worse(task, reach):
    promp, w = reach
    envs = torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64)
    exact, light = _run(task, promp, w, envs), _run(task, promp, w, envs, mass_scale=0.7)
    assert light.tracking_rms[0] > 10 * exact.tracking_rms[0]


def test_a_broken_mean_is_a_named_failure_not_a_crash(task, reach):
    promp, w = reach
    bad = w.clone()
    bad[0, 3] = float("nan")
    envs = torch.tensor([[0.55, 0.30, 0.70, -0.10]] * 2, dtype=torch.float64)
    res = _run(task, promp, torch.cat([w, bad]), envs)
    assert res.success.tolist() == [True, False]
    assert res.failures["diverged"][1] or res.failures["saturated"][1]
    s = res.summary()
    assert (
        s["nonfinite_torque_episodes"] == 1
        and s["failures"]["diverged"] + s["failures"]["saturated"] >= 1
    )
    assert all(np.isfinite(v) for v in s.values() if isinstance(v, float))


class _SwitchAt:
    """A system that tracks ``first`` until control step ``k``, then ``then`` (a class switch)."""

    def __init__(self, first, then, k):
        self.first, self.then, self.k = first, then, k

    def answer(self, t, z, q, qd=None):
        return self.first if t < self.k else self.then


def test_a_torque_feasible_reference_slows_where_the_motors_cannot_follow(task, reach):
    """A switch half way, from the straight reach to a detour on the right, with the reference's
    acceleration limits three times the Panda's: tracked as planned the command passes the torque
    limits (a saturation failure); with ``feasible=0.9`` the reference's acceleration is scaled
    down, every command stays within 0.9 of the limits and the episode succeeds, tracking as well
    as a reach within the limits."""
    promp, w = reach
    env = torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64)  # clear of both paths
    q, _ = task.ik_path(detour_paths(task, torch.tensor([[0.50, 0.0, 0.70, -0.10]]), 1, 0.25, 100))
    other = promp.weights(q)
    assert task.success(promp.trajectory(torch.cat([w, other])), env.expand(2, -1)).all()
    timing = check_timing(0.02, 2.0, 0.6)
    walk = env[:, None].expand(-1, timing.total + 1, -1)
    gains = GAINS | {"max_acceleration": [3 * a for a in PANDA_MAX_ACCELERATION]}
    runs = {
        f: run_physics_episodes(
            build_scene(task),
            controller_model(task),
            _SwitchAt(w, other, 50),
            promp,
            timing,
            walk,
            **gains,
            feasible=f,
        )
        for f in (None, 0.9)
    }
    plain, feasible = runs[None], runs[0.9]
    assert (
        plain.max_torque_ratio[0] > 1.0 and plain.failures["saturated"][0] and not plain.success[0]
    )
    assert feasible.max_torque_ratio[0] <= 0.9 + 1e-9 and feasible.success[0]
    assert feasible.tracking_rms[0] < 1e-4 < plain.tracking_rms[0]
    assert feasible.final_goal_distance[0] < 2e-3


def test_the_control_step_must_be_a_whole_number_of_physics_steps():
    assert substeps(0.02, 0.002) == 10
    with pytest.raises(ValueError, match="whole multiple of the physics timestep"):
        substeps(0.02, 0.003)


def test_the_executed_velocities_and_applied_torques_are_recorded(task, reach):
    promp, w = reach
    res = _run(task, promp, w, torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64))
    from protorch.sim.scene import build_scene as _scene

    limits = _scene(task).torque_limits  # (J,)
    assert res.qd.shape == res.q.shape and res.tau.shape == res.q.shape
    assert (
        np.all(np.abs(res.tau) <= limits + 1e-12) and np.abs(res.tau).max() > 1.0
    )  # gravity alone needs torque
    # the joints move by their recorded velocities: q(t + dt) - q(t) = the velocities' integral,
    # which the
    # velocities at both ends bracket to second order (dt = 20 ms, smooth motion)
    dq = res.q[:, 1:] - res.q[:, :-1]  # (E, T, J)
    trapezoid = 0.5 * (res.qd[:, 1:] + res.qd[:, :-1]) * TIMING.dt
    assert np.abs(dq - trapezoid).max() < 0.05 * np.abs(dq).max()
    assert np.abs(res.qd[:, 0]).max() == 0.0  # at rest at the start
