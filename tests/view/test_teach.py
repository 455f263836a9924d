"""The teach page's plain functions (no browser): the quality checks (on the authors' human
demonstrations and on made-up strokes), the session (resampling, keep / insist / discard, the
files it writes and their marks, the next environment, the lock), continuing a folder after the
page or the server went away, bad folders, the arm's hand following by IK, and the folders
loading into both experiments with ``task.demos``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from protorch import ProMP, demonstration_dataset, save_model
from protorch.data.dataset import TrajectoryDataset
from protorch.data.demos import PARTICLE_FORMAT, load_human_demos, read_demos, read_marks
from protorch.experiments import arm_reach, point_particle
from protorch.gp.model import label_aware_mean
from protorch.primitives.promp import resample
from protorch.tasks import PointParticleTask
from protorch.tasks.arm.demos import arm_demo_format
from protorch.view.__main__ import main, parse_args, teach_session
from protorch.view.scene import open_run
from protorch.view.teach import TeachSession, failing_envs
from protorch.view.teach_server import board_point, teach_markdown
from protorch.view.teach_tasks import ArmTeach, HandFollower, ParticleTeach

HUMAN = (
    Path(__file__).resolve().parents[2].parent / "shared" / "data" / "point_particle_human_demos"
)
ENV = torch.tensor([1.0, 2.0, 5.0, 6.5, 9.0, 3.0], dtype=torch.float64)
HOLE = [(1.0, 2.0), (2.5, 4.5), (3.6, 6.4), (5.0, 6.5), (6.4, 6.4), (7.8, 4.6), (9.0, 3.0)]
WALL = [(1.0, 2.0), (3.0, 2.5), (5.0, 2.5), (7.0, 2.8), (9.0, 3.0)]


def stroke(points, per_segment: int = 4) -> torch.Tensor:
    """A pointer stroke through ``points``: ``per_segment`` samples per straight segment."""
    p = torch.tensor(points, dtype=torch.float64)
    parts = [p[:1]] + [
        p[i]
        + (p[i + 1] - p[i]) * torch.linspace(0, 1, per_segment + 1, dtype=torch.float64)[1:, None]
        for i in range(len(p) - 1)
    ]
    return torch.cat(parts)  # (1 + per_segment (len - 1), 2)


@pytest.fixture
def session(tmp_path):
    s = TeachSession(ParticleTeach(), tmp_path / "demos", per_env=2, num_envs=2, seed=1)
    s.set_env(ENV)
    return s


# ------------------------------------------------------------------ quality checks
@pytest.mark.skipif(not HUMAN.is_dir(), reason=f"human demonstrations not found at {HUMAN}")
def test_every_human_demonstration_passes_the_checks():
    demos, envs = load_human_demos(HUMAN)
    teach = ParticleTeach()
    flagged = [
        i
        for i, (d, e) in enumerate(zip(demos, envs))
        if not teach.quality(d, resample(d, 100), e).ok
    ]
    assert flagged == []


def test_particle_checks_name_what_failed():
    teach = ParticleTeach(min_samples=10)
    good = stroke(HOLE)
    q = teach.quality(good, resample(good, 100), ENV)
    assert q.ok and q.values["clearance"] > 0.4 and q.values["samples"] == 25
    wall = stroke(WALL)
    q = teach.quality(wall, resample(wall, 100), ENV)
    assert q.flags == ("collides",) and "enters the wall" in q.messages[0]
    late = stroke([(3.0, 6.5), *HOLE[3:]])  # starts 4.9 from the start
    q = teach.quality(late, resample(late, 100), ENV)
    assert q.flags == ("start",) and q.values["start_distance"] == pytest.approx(
        float(np.hypot(2.0, 4.5))
    )
    short = stroke(HOLE, per_segment=1)  # 7 samples
    q = teach.quality(short, resample(short, 100), ENV)
    assert q.flags == ("short",)
    # a jump across the wall's lower corner between two samples: the exact segment test catches it
    corner = torch.tensor([[1.0, 2.0], [4.3, 5.0], [6.0, 6.0], [9.0, 3.0]], dtype=torch.float64)
    assert teach.quality(corner, resample(corner, 100), ENV).flags == ("short", "collides")


def test_board_point_undoes_the_parallax_of_the_grabbed_particle():
    cam = np.array([5.0, 5.0, 11.0])
    floor = np.array([8.0, 2.0, 0.0])
    on_top = cam + (floor - cam) * (11.0 - 0.04) / 11.0  # the same ray, at the particle's top face
    assert np.allclose(board_point(on_top, cam), floor)


# ------------------------------------------------------------------ the session
def test_keep_writes_the_resampled_demonstration_exactly(session):
    good = stroke(HOLE)
    shown = session.record(good)
    assert shown.quality.ok and shown.traj.shape == (100, 2)
    torch.testing.assert_close(shown.traj, resample(good, 100), rtol=0, atol=0)
    assert session.keep() == 0
    back = read_demos(session.folder, PARTICLE_FORMAT)
    assert torch.equal(back.demos[0], shown.traj) and torch.equal(
        back.envs[0], ENV
    )  # %.18e round-trips
    assert session.progress() == {
        "envs_done": 0,
        "num_envs": 2,
        "kept_here": 1,
        "per_env": 2,
        "kept": 1,
        "marked": 0,
        "finished": False,
    }
    assert not list(session.folder.glob(".*.tmp"))


def test_a_flagged_demonstration_is_kept_only_when_insisted_and_is_marked(session):
    session.record(stroke(WALL))
    with pytest.raises(ValueError, match="failed its checks.*enters the wall"):
        session.keep()
    assert session.kept == 0
    assert session.keep(insist=True) == 0
    record = json.loads((session.folder / "teach.json").read_text())
    assert (
        record["demos"]["0"]["flags"] == ["collides"] and record["demos"]["0"]["insisted"] is True
    )
    assert read_marks(session.folder) == {0: ["collides"]} and session.marked == 1
    with pytest.raises(ValueError, match="no demonstration to keep"):
        session.keep()


def test_the_environment_is_locked_until_complete_then_the_next_one_comes(session):
    session.record(stroke(HOLE))
    session.keep()
    assert session.locked
    with pytest.raises(ValueError, match="1 of 2 demonstrations are kept"):
        session.next_env()
    with pytest.raises(ValueError, match="finish it first"):
        session.set_env(ENV + 0.1)
    session.record(stroke(HOLE))
    session.set_env(ENV.clone())  # the same environment (a slider echo): the one on show stays
    assert session.pending is not None
    session.discard()
    assert session.pending is None and session.kept == 1
    session.record(stroke([(1.1, 2.0), *HOLE[1:]]))
    session.keep()
    assert session.envs_done == 1 and not session.locked and not torch.equal(session.env, ENV)
    assert session.kept_here == 0 and session.kept_paths() == []
    md = teach_markdown(session)
    assert (
        "**1 of 2** done" in md
        and "**0 of 2** kept" in md
        and "demonstrations kept: 2 (0 marked)" in md
    )


def test_a_reopened_folder_continues_where_it_stopped(session, tmp_path):
    session.record(stroke(HOLE))
    session.keep()
    session.record(stroke(WALL))  # on show, never kept: the page was closed
    folder = session.folder
    (folder / ".traj1.out.abc.tmp").write_text("half")  # a write killed mid-way
    (folder / "env1.out").write_text(
        (folder / "env0.out").read_text()
    )  # a keep killed before its trajectory
    again = TeachSession(ParticleTeach(), folder, per_env=2, num_envs=2, seed=1)
    assert (
        torch.equal(again.env, ENV) and again.kept_here == 1 and again.locked and again.next_k == 1
    )
    assert (
        len(again.notes) == 2
        and not (folder / "env1.out").exists()
        and not list(folder.glob(".*.tmp"))
    )
    assert len(again.kept_paths()) == 1 and again.pending is None
    again.record(stroke(HOLE))
    assert again.keep() == 1 and again.envs_done == 1
    assert torch.equal(
        again.env, again.proposals[0]
    )  # ENV was set by hand: the proposals start over


def test_a_reopened_folder_proposes_no_environment_it_holds(tmp_path):
    first = TeachSession(ParticleTeach(), tmp_path, per_env=2, seed=4)
    for _ in range(2):
        first.record(stroke(HOLE))
        first.keep(insist=True)  # (the stroke is not for this environment: flagged, kept anyway)
    assert torch.equal(first.env, first.proposals[1])
    again = TeachSession(ParticleTeach(), tmp_path, per_env=2, seed=4)
    assert torch.equal(again.env, first.proposals[1]) and again.marked == 2


def test_bad_folders_are_refused_naming_file_and_line(tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "traj0.out").write_text("1,2\n3,4,5\n")
    (bad / "env0.out").write_text("1\n2\n5\n5\n8\n8\n")
    with pytest.raises(ValueError, match=r"traj0\.out:2: expected 2 value"):
        TeachSession(ParticleTeach(), bad)
    arm = tmp_path / "arm"
    TeachSession(ArmTeach(), arm)  # writes nothing until a keep: a new folder is fine
    (arm / "teach.json").write_text(json.dumps({"task": "arm_reach", "demos": {}}))
    with pytest.raises(ValueError, match="holds arm_reach demonstrations"):
        TeachSession(ParticleTeach(), arm)


# ------------------------------------------------------------------ the arm
def hand_stroke(follower, waypoints, steps: int = 4):
    """Joint angles recorded while the hand is dragged through ``waypoints`` (and the
    worst miss)."""
    follower.reset()
    prev, qs, err = follower.hand.copy(), [follower.q.clone()], 0.0
    for w in waypoints:
        for a in np.linspace(0, 1, steps + 1)[1:]:
            q, e = follower.move(prev + (np.asarray(w) - prev) * a)
            qs.append(q)
            err = max(err, e)
        prev = np.asarray(w)
    return torch.stack(qs), err


def record_hand(session, follower, waypoints):
    raw, err = hand_stroke(follower, waypoints)
    return session.record(raw, ik_error=err)


ARM_ENV = torch.tensor([0.56, 0.02, 0.70, 0.06], dtype=torch.float64)


def around(dy: float, h: float = 0.1):
    """Hand waypoints from the start (0.40, 0) past the can on the left (dy > 0) or right to the
    target."""
    return [(0.46, 0.5 * dy, h), (0.56, dy, h), (0.66, 0.75 * dy, h), (0.70, 0.06, h)]


@pytest.fixture(scope="module")
def arm_teach():
    return ArmTeach()


def test_the_hand_follows_pointing_down(arm_teach):
    f = HandFollower(arm_teach.task)
    kin = arm_teach.task.kinematics
    down = kin.ee_pose(arm_teach.task.start_config())[:3, :3]
    q, err = hand_stroke(f, around(0.16))
    poses = kin.ee_pose(q)  # (n, 4, 4)
    assert err < 1e-4 and float((poses[:, :3, :3] - down).abs().max()) < 1e-3
    assert np.allclose(poses[-1, :3, 3].numpy(), [0.70, 0.06, 0.1], atol=1e-4)
    assert bool(kin.within_limits(q).all())
    _, far = f.move((1.5, 0.0, 0.1))  # out of reach: the miss is reported
    assert far > 0.3


def test_arm_checks_and_a_folder_that_trains(arm_teach, tmp_path):
    s = TeachSession(arm_teach, tmp_path / "arm", per_env=2, num_envs=1)
    s.set_env(ARM_ENV)
    f = HandFollower(arm_teach.task)
    through = record_hand(s, f, [(0.56, 0.02, 0.1), (0.70, 0.06, 0.1)])
    assert "collides" in through.quality.flags
    left = record_hand(s, f, around(0.16))
    assert left.quality.ok and left.quality.values["side"] == "left"
    s.keep()
    right = record_hand(s, f, around(-0.14))
    assert right.quality.flags == ("side",) and "on the right" in right.quality.messages[0]
    record_hand(s, f, around(0.12))
    s.keep()
    assert s.envs_done == 1 and s.progress()["finished"]
    back = read_demos(s.folder, arm_demo_format(arm_teach.task))
    assert [d.shape for d in back.demos] == [(100, 7), (100, 7)]
    exp = arm_reach.prepare(
        optimizer={"name": "pro", "beta": 200.0, "max_iter": 2, "num_samples": 10},
        task={"demos": str(s.folder), "priors": 0},
        test={"num_envs": 2},
        dynamic={"episodes": 0},
    )
    assert exp.demo_labels.tolist() == [0, 0] and torch.equal(exp.demos[1], back.demos[1])
    assert exp.describe()["demos"]["success_rate"] == 1.0  # both taught demonstrations succeed


def test_arm_folders_are_checked_naming_file_and_line(arm_teach, tmp_path):
    folder = tmp_path / "arm"
    folder.mkdir()
    q0 = ",".join(map(str, arm_teach.task.start_q))
    (folder / "env0.out").write_text("0.56\n0.02\n0.7\n0.06\n")
    (folder / "traj0.out").write_text(f"{q0}\n1,2\n")
    with pytest.raises(ValueError, match=r"traj0\.out:2: expected 7 value"):
        read_demos(folder, arm_demo_format(arm_teach.task))
    (folder / "traj0.out").write_text(f"{q0}\n{q0.replace('-2.7266', '-3.5', 1)}\n")
    with pytest.raises(
        ValueError, match=r"traj0\.out:2: panda_joint4 = -3\.5 lies outside the joint limits"
    ):
        read_demos(folder, arm_demo_format(arm_teach.task))
    (folder / "traj0.out").write_text(f"{q0}\n{q0}\n")
    (folder / "env0.out").write_text("0.56\n0.02\n2.0\n0.06\n")
    with pytest.raises(ValueError, match=r"env0\.out:3: goal_x = 2 lies outside the table"):
        read_demos(folder, arm_demo_format(arm_teach.task))
    (folder / "env0.out").write_text("0.56\n0.02\n0.7\n0.06\n")
    with pytest.raises(
        ValueError,
        match=r"env0\.out: this environment has 1 demonstration\(s\) passing left \(traj0",
    ):
        arm_reach.prepare(
            optimizer={"name": "pro", "beta": 200.0},
            task={"demos": str(folder), "priors": 0},
            test={"num_envs": 2},
            dynamic={"episodes": 0},
        )


# ------------------------------------------------------------------ with a trained run
@pytest.fixture(scope="module")
def exact_run(tmp_path_factory):
    """A point-particle map that reproduces its 10 demonstrated environments' mean paths (tiny
    variances: the GP interpolates), and fails far from them."""
    out = tmp_path_factory.mktemp("exact")
    task, promp = PointParticleTask(objectives="hole"), ProMP(2, num_basis=10, num_steps=100)
    demos, envs = task.demonstrations(10, 3, torch.Generator().manual_seed(0))
    demo = demonstration_dataset(promp, demos, envs, task_name=task.name)
    ds = TrajectoryDataset(promp, 6, task_name=task.name)
    ds.append(
        demo.env,
        demo.mean,
        torch.full_like(demo.mean, 1e-8),
        origin="demonstration",
        converged=True,
    )
    save_model(out, ds, backend="torch", alpha=1e-3)
    (out / "config.yaml").write_text("name: point_particle\ntask:\n  objectives: hole\n")
    return out, demo.env


def test_a_run_proposes_where_its_map_fails_first(exact_run, tmp_path):
    run_dir, known = exact_run
    run = open_run(run_dir)
    candidates = torch.cat(
        [known, run.task.sample_envs(10, torch.Generator().manual_seed(5))]
    )  # (20, 6)
    envs = failing_envs(run, candidates)
    ok = run.task.success(run.model.mean_trajectory(envs), envs)
    n_fail = int((~ok).sum())
    assert 5 <= n_fail <= 15 and not bool(ok[:n_fail].any()) and bool(ok[n_fail:].all())
    assert sorted(envs.tolist()) == sorted(candidates.tolist())
    session, run2 = teach_session(
        parse_args(
            [
                "--teach",
                "point_particle",
                str(run_dir),
                "--out",
                str(tmp_path / "more"),
                "--envs",
                "5",
            ]
        )
    )
    assert run2 is not None and session.num_steps == run.model.promp.num_steps
    assert not bool(
        run.task.success(run.model.mean_trajectory(session.env[None]), session.env[None])[0]
    )
    assert "the map's mean here: **FAILURE**" in teach_markdown(session, "FAILURE")
    with pytest.raises(ValueError, match="is a point_particle run, not arm_reach"):
        teach_session(parse_args(["--teach", "arm_reach", str(run_dir)]))


def test_a_taught_particle_folder_with_a_lone_demonstration_is_refused(session):
    session.record(stroke(HOLE))
    session.keep()
    with pytest.raises(
        ValueError, match=r"env0\.out: this environment has 1 demonstration\(s\) \(traj0\.out\)"
    ):
        point_particle.prepare(
            optimizer={"beta": 20.0},
            task={"demos": str(session.folder)},
            test={"num_envs": 2},
            dynamic={"episodes": 0},
            dynamic_paper={"episodes": 0},
        )


def test_the_arm_run_proposes_its_label_aware_failures_first(arm_teach, tmp_path):
    """A map of 4 environments holding the exact straight-path weights (IK), the can beside the
    path: it succeeds there, and fails at random environments."""
    task, promp = arm_teach.task, ProMP(7, num_basis=10, num_steps=100)
    known = torch.tensor(
        [
            [0.56, -0.12, 0.70, 0.20],
            [0.56, 0.12, 0.70, -0.20],
            [0.52, -0.10, 0.66, 0.12],
            [0.60, 0.10, 0.72, -0.16],
        ],
        dtype=torch.float64,
    )
    q, _ = task.ik_path(task.straight_paths(known, promp.num_steps))  # (4, T, 7)
    ds = TrajectoryDataset(promp, 4, task_name=task.name)
    w = promp.weights(q)
    ds.append(
        known,
        w,
        torch.full_like(w, 1e-8),
        label=task.side(q, known),
        origin="prior",
        converged=True,
    )
    save_model(tmp_path, ds, backend="torch", alpha=30.0)
    run = open_run(tmp_path)
    envs = torch.cat([known, task.sample_envs(8, torch.Generator().manual_seed(2))])  # (12, 4)
    out = failing_envs(run, envs)
    best = label_aware_mean(run.model.env_map, run.model.promp, run.task, out, dtype=torch.float64)
    ok = run.task.success(run.model.promp.trajectory(best.mean), out)
    n_fail = int((~ok).sum())
    assert 4 <= n_fail <= 8 and not bool(ok[:n_fail].any()) and bool(ok[n_fail:].all())
    assert sorted(out.tolist()) == sorted(envs.tolist())


def test_the_command_line_refuses_a_bad_folder_naming_file_and_line(tmp_path, capsys):
    (tmp_path / "traj0.out").write_text("1,2\nnan,4\n")
    (tmp_path / "env0.out").write_text("1\n2\n5\n5\n8\n8\n")
    assert main(["--teach", "point_particle", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("protorch view --teach: ") and "traj0.out:2: NaN or infinite value" in err


def test_the_csv_format_writes_timestamped_recordings_that_train(tmp_path):
    """``fmt="csv"``: each kept demonstration is ``demoK.csv`` (the raw samples at their times,
    the environment in every row), read back by the recordings reader, continued when reopened,
    and read for training with a trained point particle's format."""
    from protorch.data.demos import read_demo_folder
    from protorch.data.recordings import read_recording

    s = TeachSession(ParticleTeach(), tmp_path / "demos", per_env=2, num_envs=2, seed=1, fmt="csv")
    s.set_env(ENV)
    for path in (
        HOLE,
        [(1.0, 2.0), (2.6, 4.4), (3.7, 6.3), (5.0, 6.4), (6.3, 6.3), (7.7, 4.7), (9.0, 3.0)],
    ):
        raw = stroke(path, 10)  # (61, 2)
        times = (
            0.5 + torch.arange(raw.shape[0], dtype=torch.float64) / 30
        )  # 30 samples a second, 2 s
        s.record(raw, times=times)
        s.keep()
    assert sorted(p.name for p in s.folder.glob("*.csv")) == ["demo0.csv", "demo1.csv"]
    rec = read_recording(s.folder / "demo0.csv", PARTICLE_FORMAT)
    assert (
        rec.time[0] == 0
        and abs(rec.time[-1] - 2.0) < 1e-12
        and torch.equal(torch.as_tensor(rec.values), stroke(HOLE, 10))
    )
    assert rec.env.tolist() == ENV.tolist()
    again = TeachSession(
        ParticleTeach(), tmp_path / "demos", per_env=2, num_envs=2, seed=1, fmt="csv"
    )
    assert again.next_k == 2 and again.kept == 2 and again.envs_done == 1
    with pytest.raises(ValueError, match=r"holds \*\.csv recordings: teach the csv format there"):
        TeachSession(ParticleTeach(), tmp_path / "demos", per_env=2, num_envs=2, seed=1)
    folder, _ = read_demo_folder(s.folder, PARTICLE_FORMAT)
    assert len(folder.demos) == 2 and folder.report["grouping"]["groups"] == 1
