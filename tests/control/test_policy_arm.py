"""The policy on the arm: it reproduces the moving test's class choice at every instant of its
episodes, its exported program equals it without protorch, a 1 kHz MuJoCo loop driven by it
tracks a continuous reference while the can is moved, and protorch.load rebuilds a real run's
task and settings from its folder."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

import protorch
from protorch.control.arm import run_arm_episodes
from protorch.policy.policy import Policy
from protorch.tasks.arm.reach import LEFT, RIGHT, ArmReachTask

from ..policy.builders import moving_episodes, point_particle_config, two_class_arm_policy
from .test_policy import check_export

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow  # IK demonstrations and an arm map: ~20 s of CPU


@pytest.fixture(scope="module")
def policy():
    """A two-class arm map from IK demonstrations on both sides of cans near the straight line."""
    return two_class_arm_policy()


def walks(m: int) -> torch.Tensor:
    """Episodes whose can crosses the straight line at different instants: ``(E, m + 1, 4)``."""
    out = []
    for k, (y0, y1) in enumerate([(0.06, -0.06), (-0.06, 0.06), (0.04, -0.08), (0.0, 0.0)]):
        s = torch.linspace(0, 1, m + 1, dtype=F64).clamp(0.2 + 0.1 * k, 0.5 + 0.1 * k)
        s = (s - s.min()) / max(float(s.max() - s.min()), 1e-9)
        y = y0 + (y1 - y0) * s
        out.append(
            torch.stack(
                [torch.full_like(y, 0.56), y, torch.full_like(y, 0.71), torch.zeros_like(y)], -1
            )
        )
    return torch.stack(out)


@pytest.mark.parametrize("check", [False, True])
def test_the_policy_reproduces_the_moving_tests_class_switches(policy, check, monkeypatch):
    """With and without the plan check (the policy reads the run's ``dynamic.check``)."""
    task = policy.task
    monkeypatch.setattr(policy, "check", check)
    m = int(round(policy.duration / 0.02))
    same = dict(
        duration=policy.duration,
        hold=0.3,
        dt=0.02,
        switch_margin=policy.switch_margin,
        check=check,
        switch_clearance=policy.switch_clearance,
    )
    runs = [
        run_arm_episodes(policy, task, walk=walks(m), **same),
        run_arm_episodes(
            policy,
            task,
            task.sample_envs(6, torch.Generator().manual_seed(1)),
            generator=torch.Generator().manual_seed(2),
            **same,
        ),
    ]
    switches = 0
    for res in runs:
        switches += int(res.switches.sum())
        for e in range(res.q.shape[0]):
            policy.reset()
            got = [
                policy.reference(res.envs[e, i], i * res.dt, res.q[e, i], res.qd[e, i]).label
                for i in range(res.q.shape[1])
            ]
            assert got == res.labels[e].tolist(), e
    assert switches >= 1  # the episodes do switch classes


def test_the_checked_choice_never_tracks_a_blocked_plan_while_another_is_clear(policy):
    """At every decision of the moving test with ``check``, the tracked class's plan for the rest
    of the motion from the arm's joints and velocities clears the can, unless every class's plan
    touches it (then the tracked one keeps the largest gap, another class's larger only by more
    than half of ``switch_clearance``); and the check changes decisions on these episodes (against
    ``check=False``)."""
    from protorch.control.arm import arm_follow
    from protorch.control.arm_choice import rest_blocked, rest_clearance
    from protorch.control.episodes import check_timing

    task = ArmReachTask(cost_steps=6, collision="volume")
    envs = task.sample_envs(30, torch.Generator().manual_seed(1))
    runs = {
        c: run_arm_episodes(
            policy,
            task,
            envs,
            duration=policy.duration,
            hold=0.3,
            dt=0.02,
            switch_margin=policy.switch_margin,
            generator=torch.Generator().manual_seed(2),
            check=c,
            switch_clearance=policy.switch_clearance,
        )
        for c in (False, True)
    }
    res = runs[True]
    assert bool((runs[False].labels != res.labels).any())
    grid = policy.promp.phase[task.cost_indices(policy.promp.num_steps)].to(F64)
    cand = torch.unique(policy.env_map.labels)
    moving = res.num_moving_steps
    timing = check_timing(0.02, policy.duration, 0.3)
    follow = arm_follow(
        task, 10.0, task.robot.max_acceleration, timing
    )  # run_arm_episodes' velocity command
    passed_over = 0
    for i in range(moving + 1):
        z = timing.phase(i)
        env = res.envs[:, i]  # (E, 4)
        means = torch.stack(
            [policy.env_map.predict_mean(env, torch.full((env.shape[0],), int(c))) for c in cand]
        )
        args = (
            task,
            policy.promp,
            means.to(F64),
            env,
            res.q[:, i],
            z,
            grid[grid > z],
            res.qd[:, i],
            follow,
        )
        blocked = rest_blocked(*args)  # (K, E)
        chosen = (res.labels[:, i][None] == cand[:, None]).to(torch.long).argmax(0)  # (E,)
        on_blocked = blocked.gather(0, chosen[None])[0]
        assert not bool((on_blocked & ~blocked.all(0)).any()), i
        stuck = blocked.all(0)
        if bool(stuck.any()):
            gap = rest_clearance(*args)[:, stuck]  # (K, n)
            # the class tracked until now keeps it unless another's gap is larger by
            # switch_clearance
            if i:
                prev = (
                    (res.labels[:, i - 1][None] == cand[:, None]).to(torch.long).argmax(0)[stuck]
                )  # (n,)
                gap = gap - 0.5 * policy.switch_clearance * (
                    torch.arange(len(cand))[:, None] != prev
                )
            assert torch.equal(chosen[stuck], gap.argmax(0)), i
        passed_over += int((blocked.any(0) & ~blocked.all(0)).sum())
    assert passed_over >= 1


def test_the_policy_reproduces_the_checks_hysteresis_on_the_volumes(policy):
    """With the link volumes the check's hysteresis (``switch_clearance``) changes the moving
    test's classes on these episodes and cuts its switches; the policy, given each instant's
    environment, joints and velocities, still picks the test's class at every instant."""
    task = ArmReachTask(cost_steps=6, collision="volume")
    volume = Policy(
        policy._P,
        policy.env_map,
        "arm_reach",
        task=task,
        duration=policy.duration,
        switch_margin=0.02,
        decision_dt=0.02,
        check=True,
        switch_clearance=0.01,
    )
    envs = task.sample_envs(12, torch.Generator().manual_seed(1))
    runs = {
        sc: run_arm_episodes(
            volume,
            task,
            envs,
            duration=volume.duration,
            hold=0.3,
            dt=0.02,
            switch_margin=0.02,
            generator=torch.Generator().manual_seed(2),
            check=True,
            switch_clearance=sc,
        )
        for sc in (0.0, 0.01)
    }
    res = runs[0.01]
    assert bool((runs[0.0].labels != res.labels).any())
    assert int(res.switches.sum()) < int(runs[0.0].switches.sum())
    for e in range(res.q.shape[0]):
        volume.reset()
        got = [
            volume.reference(res.envs[e, i], i * res.dt, res.q[e, i], res.qd[e, i]).label
            for i in range(res.q.shape[1])
        ]
        assert got == res.labels[e].tolist(), e
    assert (
        volume._memo.passed >= 1 and volume._memo.checked >= 1
    )  # plans passed by the carried bounds, and not


@pytest.mark.parametrize("check", [False, True])
def test_the_exported_arm_program_runs_without_protorch_and_equals_reference(
    policy, tmp_path, check, monkeypatch
):
    monkeypatch.setattr(policy, "check", check)
    envs = policy.task.sample_envs(200, torch.Generator().manual_seed(3))
    check_export(policy, tmp_path, envs, calls=300)


def test_the_exported_volume_program_writes_nothing_in_place(policy, tmp_path, monkeypatch):
    """With the link volumes and the plan check the exported graph holds no in-place operation:
    AOTInductor (``export(aoti=True)``) refuses a graph that writes into a slice of a constant."""
    volume = Policy(
        policy._P,
        policy.env_map,
        "arm_reach",
        task=ArmReachTask(cost_steps=6, collision="volume"),
        duration=1.5,
        switch_margin=0.02,
        decision_dt=0.02,
    )
    monkeypatch.setattr(volume, "check", True)
    program = torch.export.load(volume.export(tmp_path / "volume.pt2"))
    mutating = sorted(
        {
            str(n.target)
            for n in program.graph.nodes
            if n.op == "call_function"
            and getattr(getattr(n.target, "_schema", None), "is_mutable", False)
        }
    )
    assert not mutating, f"in-place operations in the exported graph: {mutating}"
    module = program.module()
    for env in volume.task.sample_envs(20, torch.Generator().manual_seed(5)):
        volume.reset()
        r = volume.reference(env, 0.4)
        q, qd, qdd, label = module(env, torch.tensor(0.4, dtype=F64))
        torch.testing.assert_close(q, r.q, rtol=0, atol=1e-9)
        assert int(label) == r.label


def _example():
    spec = importlib.util.spec_from_file_location(
        "control_loop_example", ROOT / "examples" / "control_loop.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_1khz_mujoco_loop_tracks_a_continuous_reference_while_the_can_moves(policy):
    pytest.importorskip("mujoco", minversion="4.0", reason="the physics extra is not installed")
    ex = _example()
    env0 = np.array(
        [0.56, 0.06, 0.71, 0.0]
    )  # the can slides across the straight path early in the motion
    log = ex.control_loop(policy, ex.person(env0, np.array([0.56, -0.08]), 0.15, 0.2), seconds=1.2)
    assert log["q"].shape == (1200, 7) and np.isfinite(log["q"]).all()
    assert set(log["label"].tolist()) == {
        LEFT,
        RIGHT,
    }  # the person's move made the arm change sides
    step = np.abs(np.diff(log["q_r"], axis=0)).max()
    speed = np.abs(log["qd_r"]).max()
    assert step <= 1.01 * speed * 1e-3 + 1e-12  # no jump: the reference moves by its own velocity
    # the reference starts at the measured joints and the computed-torque controller keeps the arm
    # on it
    assert np.abs(log["q_r"][0] - log["q"][0]).max() < 1e-12
    assert np.abs(log["q_r"] - log["q"]).max() < 5e-3
    assert (np.abs(log["tau"]) <= log["limits"] + 1e-12).all()


def test_load_rebuilds_a_runs_task_and_settings_from_its_folder(tmp_path):
    from protorch.experiments import run_experiment

    cfg = {
        "name": "arm_reach",
        "seed": 0,
        "plot": False,
        "optimizer": {
            "name": "pro",
            "beta": 200.0,
            "max_iter": 3,
            "num_samples": 20,
            "relevance_samples": 20,
        },
        "gp": {"backend": "torch", "alpha": 30.0, "var_floor": 1e-3, "nearest_k": 30},
        "task": {
            "_target_": "protorch.tasks.ArmReachTask",
            "priors": 50,
            "demo_envs": 4,
            "cost_steps": 10,
        },
        "settings": {
            "loop": {"num_envs": 10, "batch_size": 10},
            "test": {"num_envs": 5},
            "dynamic": {
                "episodes": 2,
                "duration": 2.5,
                "switch_margin": 0.03,
                "switch_clearance": 0.015,
            },
            "physics": {"run": "never"},
            "baselines": [],
            "progress": False,
        },
    }
    run_experiment(cfg, tmp_path)
    assert (tmp_path / "config.yaml").is_file()
    pol = protorch.load(tmp_path)
    assert isinstance(pol.task, ArmReachTask) and pol.task.cost_steps == 10
    assert (pol.duration, pol.switch_margin, pol.decision_dt, pol.switch_clearance) == (
        2.5,
        0.03,
        0.02,
        0.015,
    )
    assert pol.check  # the run's moving-test settings, its check's hysteresis included
    assert pol.labels.tolist() == [LEFT, RIGHT]
    envs = pol.task.sample_envs(3, torch.Generator().manual_seed(0))
    assert pol.mean_trajectory(envs).shape == (3, 100, 7)  # the class chosen, no labels= needed
    r = pol.reference(envs[0], 0.5)
    assert r.q.shape == (7,) and r.label in (LEFT, RIGHT)
    with pytest.raises(ValueError, match=r"env must be \(4,\)"):
        pol.reference(envs[0, :3], 0.5)


def test_load_gives_a_point_particle_run_as_a_policy(tmp_path):
    from protorch.control.episodes import promp_state_at
    from protorch.experiments import run_experiment
    from protorch.tasks import PointParticleTask

    cfg = point_particle_config(
        max_iter=5, samples=20, demo_envs=6, num_envs=10, test=5, episodes=2
    )
    run_experiment(cfg, tmp_path)
    pol = protorch.load(tmp_path)
    assert (
        isinstance(pol.task, PointParticleTask) and pol.labels.numel() == 1 and pol.duration == 2.0
    )
    envs = pol.task.sample_envs(20, torch.Generator().manual_seed(0))
    for e in envs[:5]:
        pol.reset()
        w = pol.env_map.predict_mean(e[None])[0]
        for t in (0.0, 0.7, 2.5):
            pos, dpos = promp_state_at(pol.promp, w, min(t / pol.duration, 1.0))
            r = pol.reference(e, t)
            torch.testing.assert_close(r.q, pos, rtol=0, atol=1e-12)
            torch.testing.assert_close(
                r.qd, dpos / pol.duration if t < pol.duration else 0 * pos, rtol=0, atol=1e-12
            )
    check_export(pol, tmp_path, envs, calls=200)


@pytest.mark.parametrize("limits", [True, "together"])
def test_the_threaded_reference_keeps_the_robots_limits_through_the_moving_tests_switches(
    policy, limits
):
    """The moving test's episodes (the can crossing the arm's path, switches included) replayed at
    1 kHz through ``planner="thread"`` with a plan made every 5 ms on the inputs of that tick (the
    planner thread's rhythm, made deterministic here): between consecutive ticks the velocity,
    acceleration and jerk stay within the Panda's published limits (a class switch's offset asks for
    more acceleration than joint 2's 7.5 rad/s^2: Ruckig's hand-overs to the new plan's motion take
    over there), the reference never jumps and is back on the plan by the end of the hold."""
    task = policy.task
    res = moving_episodes(policy)
    pol = Policy(
        policy._P,
        policy.env_map,
        "arm_reach",
        task=task,
        duration=policy.duration,
        switch_margin=policy.switch_margin,
        decision_dt=0.02,
        switch_clearance=policy.switch_clearance,
        planner="thread",
        plan_period=1e6,
        warm_up=False,
        limits=limits,
    )
    lim = pol._limiter
    vmax, amax, jmax = lim.vmax, lim.amax, lim.jmax
    np.testing.assert_array_equal(vmax, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_array_equal(jmax, [7500.0] * 7)
    per = round(res.dt * 1000)
    worst, switches = np.zeros(3), 0
    for e in (
        torch.nonzero(res.switches > 0).flatten()[:1].tolist()
    ):  # the first episode with a switch
        pol.reset(res.envs[e, 0], res.q[e, 0], res.qd[e, 0])
        states, labels = [], []
        for i in range((res.q.shape[1] - 1) * per + 1):
            s, t = i // per, i * 1e-3
            env, q, qd = res.envs[e, s], res.q[e, s], res.qd[e, s]
            if i and i % 5 == 0:
                with pol._planner.lock:
                    pol._planner.plan = pol._plan(
                        pol._motion, env.numpy(), t, q.numpy(), qd.numpy()
                    )
            r = pol.reference(env, t, q, qd)
            states.append(torch.stack([r.q, r.qd, r.qdd]).numpy())
            labels.append(r.label)
        x = np.stack(states)  # (T, 3, D)
        switches += int((np.diff(labels) != 0).sum())
        jerk = np.abs(np.diff(x[:, 2], axis=0)) / 1e-3
        worst = np.maximum(
            worst,
            [(np.abs(x[:, 1]) / vmax).max(), (np.abs(x[:, 2]) / amax).max(), (jerk / jmax).max()],
        )
        assert np.abs(np.diff(x[:, 0], axis=0)).max() <= np.abs(x[:, 1]).max() * 1e-3 * 1.01 + 1e-12
        end = pol._tracker.phi_end @ pol._tracker.plan.W  # (3, D) the last plan's mean, held
        assert np.abs(x[-1, 0] - end[0]).max() < 1e-4  # back on the plan by the end of the hold
    assert switches >= 1
    assert (worst <= 1 + 1e-9).all(), worst
    assert lim.failed == 0
