"""The moving test's episodes driven by the policy (:mod:`protorch.control.policy_episodes`):
inline it is the moving test itself, the planner a step behind tracks each plan one control step
late, and the real planner thread runs a paced episode."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from protorch.control.episodes import check_timing
from protorch.control.policy_episodes import PolicyMeans, policy_copy, run_policy_episodes

from .builders import moving_episodes, two_class_arm_policy

F64 = torch.float64
pytestmark = pytest.mark.slow  # IK demonstrations and an arm map


@pytest.fixture(scope="module")
def policy():
    """A two-class arm map from IK demonstrations on both sides of cans near the straight line."""
    return two_class_arm_policy(check=True, warm_up=False)


@pytest.fixture(scope="module")
def moving(policy):
    """The moving test's episodes (random moves of the can and the target), with switches."""
    res = moving_episodes(policy)
    return res, check_timing(0.02, policy.duration, 0.3)


def test_inline_through_the_policy_is_the_moving_test(policy, moving):
    """The policy's plan tracked at once: the moving test's class at every instant, its joints."""
    res, timing = moving
    got = run_policy_episodes(policy, res.envs, timing, "inline")
    np.testing.assert_array_equal(got["labels"], res.labels.numpy())
    np.testing.assert_allclose(got["q"], res.q.numpy(), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got["success"], res.success.numpy())
    assert (got["age"] == 0).all()


def test_the_lagged_planner_tracks_each_plan_one_step_late(policy, moving):
    """Every instant after the first tracks the plan made from the previous instant's inputs
    (its age one control step); lag 0 is inline exactly."""
    res, timing = moving
    envs = res.envs[:2]
    late = PolicyMeans([policy_copy(policy) for _ in range(2)], envs, timing, "lagged", lag=1)
    now = PolicyMeans([policy_copy(policy) for _ in range(2)], envs, timing, "inline")
    q, qd = res.q[:2].to(F64), res.qd[:2].to(F64)  # (2, T+1, J) the test's joints, fed to both
    prev = None
    for t in range(timing.total + 1):
        w_late = late.answer(t, timing.phase(t), q[:, t], qd[:, t])
        w_now = now.answer(t, timing.phase(t), q[:, t], qd[:, t])
        torch.testing.assert_close(w_late, w_now if prev is None else prev, rtol=0, atol=0)
        prev = w_now
    np.testing.assert_allclose(late.age[:, 1:], timing.dt, rtol=1e-12)
    assert late.labels[:, 1:].tolist() == now.labels[:, :-1].tolist()
    zero = run_policy_episodes(policy, envs, timing, "lagged", lag=0)
    inline = run_policy_episodes(policy, envs, timing, "inline")
    np.testing.assert_array_equal(zero["q"], inline["q"])


def test_the_thread_runs_a_paced_episode_on_the_planners_plans(policy, moving):
    """The real planner thread: the episode paced at real time, every instant tracks a plan made
    from the inputs of an earlier or the same control step (none from the future), and plans
    made during the episode are tracked (how far behind depends on the machine's load)."""
    res, timing = moving
    e = int(torch.nonzero(res.switches > 0)[0])
    got = run_policy_episodes(policy, res.envs[e : e + 1], timing, "thread")
    age = got["age"][0]  # (T+1,)
    steps = age / timing.dt
    assert (steps >= -1e-9).all()
    np.testing.assert_allclose(steps, np.round(steps), rtol=0, atol=1e-9)
    assert age[-1] < timing.total * timing.dt  # not the motion's first plan to the end
    assert got["labels"].shape == (1, timing.total + 1)


def test_bad_modes_are_refused(policy, moving):
    res, timing = moving
    with pytest.raises(ValueError, match="mode must be one of"):
        PolicyMeans([policy], res.envs[:1], timing, "later")
    with pytest.raises(ValueError, match="planner='thread'"):
        PolicyMeans([policy], res.envs[:1], timing, "thread")
    with pytest.raises(ValueError, match="E = 2 policies"):
        PolicyMeans([policy, policy], res.envs[:1], timing, "inline")


def _within(states: np.ndarray, dt: float, lim) -> np.ndarray:
    """The largest ``|qd| / vmax``, ``|qdd| / amax``, ``|jerk| / jmax`` over ``(E, T+1, 3, D)``."""
    vmax, amax, jmax = lim
    jerk = np.abs(np.diff(states[:, :, 2], axis=1)) / dt
    return np.array(
        [
            (np.abs(states[:, :, 1]) / vmax).max(),
            (np.abs(states[:, :, 2]) / amax).max(),
            (jerk / jmax).max(),
        ]
    )


def test_the_limited_reference_keeps_the_limits_through_the_moving_tests_switches(policy, moving):
    """The arm following the policy's reference with the robot's limits (the planner a step
    behind), closed loop over the moving test's episodes, switches included: the reference's
    velocity, acceleration and jerk within the Panda's published limits at every control step;
    without the limits a switch asks for more (the check is not vacuous)."""
    from protorch.policy.limits import robot_limits

    res, timing = moving
    lim = robot_limits(policy.task.robot, 7)
    on = run_policy_episodes(policy, res.envs, timing, "lagged", follow="reference", limits=True)
    off = run_policy_episodes(policy, res.envs, timing, "lagged", follow="reference", limits=False)
    assert int(on["switches"].sum()) >= 1
    worst = _within(on["states"], timing.dt, lim)
    assert (worst <= 1 + 1e-9).all(), worst
    assert _within(off["states"], timing.dt, lim).max() > 1
    # no jump: the position moves by at most the velocity limit over a control step
    step = np.abs(np.diff(on["states"][:, :, 0], axis=1)).max(axis=(0, 1))  # (D,)
    assert (step <= lim[0] * timing.dt * (1 + 1e-9)).all(), step


def test_the_example_loop_runs_the_threaded_policy_within_the_limits(policy):
    """examples/control_loop.py's 1 kHz MuJoCo loop, paced at real time, with ``planner="thread"``
    and the robot's limits (a small budget: 0.4 s): it logs every tick's call time and plan age
    (never negative), the reference keeps the Panda's velocity, acceleration and jerk limits
    between ticks, and the start and slide are laid out in the task's own workspace."""
    import importlib.util
    from pathlib import Path

    pytest.importorskip("mujoco", minversion="4.0", reason="the physics extra is not installed")
    path = Path(__file__).resolve().parents[2] / "examples" / "control_loop.py"
    spec = importlib.util.spec_from_file_location("control_loop_example", path)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    env0, to = ex.start_and_slide(policy.task, None, None)
    np.testing.assert_allclose(env0, [0.56, 0.03, 0.70, -0.05])  # the Panda's workspace
    np.testing.assert_allclose(to, [0.56, -0.09])
    pol = policy_copy(policy, planner="thread", limits=True)
    try:
        log = ex.control_loop(pol, ex.person(env0, to, 0.1, 0.2), seconds=0.4, realtime=True)
    finally:
        pol.close()
    assert log["q"].shape == (400, 7) and np.isfinite(log["q"]).all()
    assert (log["plan_age"] >= 0).all() and (log["seconds"] > 0).all()
    lim = pol._limiter
    jerk = np.abs(np.diff(log["qdd_r"], axis=0)) / 1e-3
    assert (np.abs(log["qd_r"]) <= lim.vmax * (1 + 1e-9)).all()
    assert (np.abs(log["qdd_r"]) <= lim.amax * (1 + 1e-9)).all()
    assert (jerk <= lim.jmax * (1 + 1e-6)).all()


def test_the_mujoco_arm_follows_the_default_limited_reference_at_every_physics_step(policy, moving):
    """MuJoCo's reference follows the policy's (``follow="reference"``, the planner a step
    behind): by default (``limits="auto"``) it keeps the Panda's velocity, acceleration and jerk
    limits at every physics step (2 ms) of the moving test's episodes, switches included, the
    last physics step of a control step to the next included; ``limits=False`` asks for more."""
    pytest.importorskip("mujoco", minversion="4.0", reason="the physics extra is not installed")
    from protorch.sim.scene import build_scene, controller_model

    res, timing = moving
    task = policy.task
    e = torch.arange(res.envs.shape[0])
    phys = dict(
        scene=build_scene(task),
        ctrl_model=controller_model(task),
        kp=400.0,
        kd=40.0,
        ref_kp=10.0,
        max_acceleration=task.robot.max_acceleration,
    )
    on = run_policy_episodes(
        policy, res.envs[e], timing, "lagged", physics=phys, follow="reference"
    )
    off = run_policy_episodes(
        policy, res.envs[e], timing, "lagged", physics=phys, follow="reference", limits=False
    )
    assert int(on["switches"].sum()) >= 1
    assert (on["peaks"] <= 1 + 1e-9).all(), on["peaks"]  # finite differences at 2 ms too
    assert on["peaks"][:, 2].max() > 0.99  # the jerk limit was reached: a hand-over at 2 ms
    assert off["peaks"][:, 1:3].max() > 1.5, off["peaks"]
    # the control steps' references are the tracker's at those instants, limited there too
    assert np.isfinite(on["q"]).all() and on["states"].shape == (len(e), timing.total + 1, 3, 7)
    with pytest.raises(ValueError, match="modes 'inline' and 'lagged'"):
        run_policy_episodes(
            policy, res.envs[e[:1]], timing, "thread", physics=phys, follow="reference"
        )
