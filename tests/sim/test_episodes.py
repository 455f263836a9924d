"""Physics episodes (protorch.sim.episodes): a reach the can does not block succeeds with the
controller tracking to a fraction of a millimetre, a can in the way is hit and named, a wrong
controller model costs tracking accuracy, and a broken mean is a named failure, never a crash."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from protorch.control.episodes import check_timing
from protorch.robots.panda import PANDA_MAX_ACCELERATION
from protorch.sim.episodes import FixedMeans, run_physics_episodes, substeps
from protorch.sim.scene import build_scene, controller_model

TIMING = check_timing(0.02, 1.5, 0.4)
GAINS = dict(kp=400.0, kd=40.0, ref_kp=10.0, max_acceleration=PANDA_MAX_ACCELERATION)


def _run(task, promp, w, envs, mass_scale=1.0):
    walk = envs[:, None].expand(-1, TIMING.total + 1, -1)
    return run_physics_episodes(build_scene(task), controller_model(task, mass_scale=mass_scale), FixedMeans(w),
                                promp, TIMING, walk, **GAINS)


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
    assert s["nonfinite_torque_episodes"] == 1 and s["failures"]["diverged"] + s["failures"]["saturated"] >= 1
    assert all(np.isfinite(v) for v in s.values() if isinstance(v, float))


def test_the_control_step_must_be_a_whole_number_of_physics_steps():
    assert substeps(0.02, 0.002) == 10
    with pytest.raises(ValueError, match="whole multiple of the physics timestep"):
        substeps(0.02, 0.003)
