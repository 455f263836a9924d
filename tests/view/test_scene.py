"""The viewer's plain functions (no browser): run discovery, task rebuilding, scene states and
the step-wise live controllers, on a small point-particle run built from demonstrations."""

from __future__ import annotations

import os

import pytest
import torch

from protorch.gp.model import label_aware_mean
from protorch.view.__main__ import main
from protorch.view.live import ArmPlayer, ParticlePlayer
from protorch.view.scene import (
    MAKE_RUN,
    find_runs,
    open_run,
    run_task_name,
    scene_state,
    weight_noise,
)


@pytest.fixture(scope="module")
def run(particle_run_dir):
    return open_run(particle_run_dir)


def test_open_run_rebuilds_the_task_from_the_config(run):
    assert run.kind == "particle" and run.model.task_name == "point_particle"
    assert run.task.objectives == "clearance"  # from config.yaml, not the class default "hole"
    assert [p.name for p in run.params] == [
        "start_x",
        "start_y",
        "wall_x",
        "hole_y",
        "goal_x",
        "goal_y",
    ]


def test_scene_state_is_the_maps_answer(run):
    env = torch.tensor([1.0, 2.0, 5.0, 6.5, 9.0, 3.0], dtype=torch.float64)
    eps = weight_noise(run.model.promp.num_weights, 8)
    s = scene_state(run, env, eps)
    mu, var = run.model.env_map.predict(env[None])
    mean = run.model.promp.trajectory(mu)[0]  # (T, 2)
    assert torch.allclose(torch.as_tensor(s.mean[:, :2]), mean) and (s.mean[:, 2] == 0).all()
    sample0 = run.model.promp.trajectory(mu + var.sqrt() * eps[:1])[0]
    assert torch.allclose(torch.as_tensor(s.samples[0, :, :2]), sample0)
    assert s.success == bool(run.task.success(mean[None], env[None])[0])
    assert s.costs == pytest.approx(
        dict(zip(run.task.objective_names, run.task.costs(mean, env).tolist()))
    )
    assert 0 < s.infer_ms <= s.total_ms
    # a zero-variance direction: a sample with eps = 0 is the mean itself
    z = scene_state(run, env, torch.zeros(1, run.model.promp.num_weights, dtype=torch.float64))
    assert torch.allclose(torch.as_tensor(z.samples[0]), torch.as_tensor(z.mean))


def test_clamp_and_bad_env(run):
    c = run.clamp([-5.0, 20.0, 0.0, 9.5, 11.0, 5.0])
    assert c.tolist() == [0.0, 10.0, 2.0, 9.0, 10.0, 5.0]
    with pytest.raises(ValueError, match="6 values"):
        run.clamp([1.0, 2.0])
    with pytest.raises(ValueError, match="NaN"):
        run.clamp([float("nan")] * 6)


def test_find_runs_newest_first_and_skips_other_tasks(tmp_path, particle_run_factory):
    a = particle_run_factory(tmp_path / "a")
    b = particle_run_factory(tmp_path / "nested" / "b")
    os.utime(a / "checkpoint" / "dataset.safetensors", (1e9, 1e9))
    (tmp_path / "junk" / "checkpoint").mkdir(parents=True)
    (tmp_path / "junk" / "checkpoint" / "dataset.safetensors").write_bytes(b"not a checkpoint")
    assert find_runs(tmp_path) == [b, a]
    assert run_task_name(tmp_path / "junk") is None and find_runs(tmp_path / "missing") == []


def test_cli_without_runs_says_how_to_make_one(tmp_path, capsys):
    assert main(["--runs", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert MAKE_RUN in out and out.count("\n") == 1


def test_live_particle_tracks_a_static_environment_to_the_goal(run):
    env = torch.tensor([1.0, 2.0, 5.0, 6.5, 9.0, 3.0], dtype=torch.float64)
    p = ParticlePlayer(run)
    p.reset(env)
    while not p.done:
        p.step(env)
    mean = scene_state(run, env, weight_noise(run.model.promp.num_weights, 1)).mean
    assert p.t == p.total == 250
    # the PD with feed-forward ends on the mean's end point (the hold settles it)
    assert abs(p.trace()[-1] - mean[-1]).max() < 1e-3
    assert p.success == (not p.collided and bool((p.pos - env[4:6]).norm() <= 0.2))


@pytest.mark.slow
def test_arm_state_is_the_label_aware_answer(arm_run_dir):
    run = open_run(arm_run_dir)
    assert run.kind == "arm" and [p.name for p in run.params] == [
        "can_x",
        "can_y",
        "goal_x",
        "goal_y",
    ]
    env = run.env0
    s = scene_state(run, env, weight_noise(run.model.promp.num_weights, 4))
    best = label_aware_mean(
        run.model.env_map, run.model.promp, run.task, env[None], dtype=torch.float64
    )
    traj = run.model.promp.trajectory(best.mean)  # (1, T, 7)
    assert s.label == {0: "left", 1: "right"}[int(best.label[0])]
    assert s.scores == pytest.approx(dict(zip(["left", "right"], best.scores[0].tolist())))
    assert torch.allclose(torch.as_tensor(s.mean), run.task.ee_path(traj)[0])
    assert s.success == bool(run.task.success(traj, env[None])[0])
    assert s.links.shape == (5, run.task.kinematics.num_frames, 3)
    assert torch.allclose(
        torch.as_tensor(s.links[-1, -1]), torch.as_tensor(s.mean[-1])
    )  # the hand ends the path
    p = ArmPlayer(run)
    p.reset()
    while not p.done:
        p.step(env)
    assert p.t == p.total == 200 and p.label in ("left", "right") and isinstance(p.success, bool)


def test_an_arm_run_is_rebuilt_with_its_robot_and_the_teach_page_takes_one(tmp_path):
    from protorch.view.__main__ import parse_args, teach_session
    from protorch.view.scene import build_task
    from tests.robots.user_arm import user_arm_home, write_user_arm

    robot = {
        "base": None,
        "urdf": str(write_user_arm(tmp_path)),
        "end_link": "tool0",
        "home": user_arm_home(),
    }
    # a run's config holds its whole workspace (auto would measure this arm's own)
    workspace = {
        "can_box": [[0.50, 0.62], [-0.12, 0.12]],
        "table": [[0.2, 0.9], [-0.5, 0.5]],
        "can_radius": 0.0375,
        "can_height": 0.23,
    }
    task = build_task(
        "arm_reach",
        {"goal_tol": 0.03, "goal_box": [[0.6, 0.7], [-0.2, 0.2]], **workspace},
        robot,
    )
    assert task.num_dof == 6 and task.robot.name == "my_arm" and task.goal_tol == 0.03
    assert task.goal_box == ((0.6, 0.7), (-0.2, 0.2))
    assert build_task("arm_reach", {}).robot.name == "Panda"  # a run from before the robot setting
    volume = build_task(
        "arm_reach",
        {"collision": "volume", "deviation": "time", "demos": "synthetic", "priors": 20},
    )
    assert (volume.collision, volume.can_objective, volume.deviation) == (
        "volume",
        "volume",
        "time",
    )  # the run's models
    assert (
        volume.capsule_plan is not None and volume.margin == 0.01
    )  # checked as the run was, not by the skeleton
    (tmp_path / "robot.yaml").write_text(
        f"urdf: {robot['urdf']}\nend_link: tool0\nhome: {user_arm_home()}\n"
    )
    args = parse_args(
        [
            "--teach",
            "arm_reach",
            "--robot",
            str(tmp_path / "robot.yaml"),
            "--out",
            str(tmp_path / "d"),
        ]
    )
    session, _ = teach_session(args)
    assert session.teach.task.num_dof == 6


def test_the_live_arm_is_the_moving_tests_arm(arm_run_dir):
    """ArmPlayer chooses and moves as the moving test does (one implementation: the run's policy's
    choice with its plan check and hysteresis, the test's velocity command): the same class at
    every step and the same joints, the can sliding across the arm's path."""
    from protorch.control.arm import run_arm_episodes

    run = open_run(arm_run_dir)
    p = ArmPlayer(run, duration=1.0, hold=0.2)
    assert (
        p.policy.check and p.policy.switch_clearance == 0.01
    )  # the moving test's defaults (no config.yaml)
    m = p.moving
    y = torch.linspace(0.08, -0.08, m + 1, dtype=torch.float64)
    walk = torch.stack(
        [torch.full_like(y, 0.56), y, torch.full_like(y, 0.70), torch.full_like(y, 0.02)], -1
    )  # (M + 1, 4)
    res = run_arm_episodes(run.model, run.task, walk=walk[None], duration=1.0, hold=0.2, dt=p.dt)
    p.reset()
    labels, qs = [], [p.q]
    while not p.done:
        p.step(walk[min(p.t, m)])
        labels.append(int(p.cand[p.current]))
        qs.append(p.q)
    assert labels == res.labels[0, : p.total].tolist()
    torch.testing.assert_close(torch.stack(qs), res.q[0], rtol=0, atol=1e-9)
    seen = walk[torch.arange(p.total).clamp(max=m)]  # (total, 4) the environment at each step
    gaps = run.task.can_gap(
        res.q[0, 1 : p.total + 1, None], seen
    )  # (total,) each new pose against that step's can
    assert p.min_distance == pytest.approx(
        float(gaps.min()), abs=1e-9
    )  # the task's collision model (volumes)
    assert p.collided == bool(gaps.min() <= run.task.margin)
    assert len(set(labels)) == 2  # the sliding can makes the arm change sides
