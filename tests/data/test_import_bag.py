"""ROS bags in (protorch.data.import_bag): ROS 2 (MCAP, sqlite3) and ROS 1 bags written with
rosbags'
own writers (benchmarks/recordings.py) import to the same file, byte for byte, as the recording
written
directly; a missing topic or joint is one line naming it, and nothing is written."""

from __future__ import annotations

import filecmp

import numpy as np
import pytest

pytest.importorskip("rosbags")

from protorch.data.import_bag import env_columns, import_bags, main, parse_env, recording_table
from protorch.data.recordings import read_recording, write_recording
from protorch.tasks.arm.demos import arm_demo_format
from protorch.tasks.arm.reach import ArmReachTask
from tests.benchmarks import benchmark_module

ENV = "can=/can_pose,goal=/target_pose"


@pytest.fixture(scope="module")
def arm():
    task = ArmReachTask()
    fmt = arm_demo_format(task)
    rng = np.random.default_rng(0)
    with benchmark_module("recordings.py", "bench_recordings") as bench:
        demos, envs, _ = bench.synthetic_demos(task, 0, envs=1, per_env=1)
        lo, hi = task.kinematics.lower.numpy(), task.kinematics.upper.numpy()
        ns, q, poses = bench.record(
            demos[0].numpy(),
            envs[0].numpy(),
            100,
            rng,
            lo,
            hi,
            duration=(1.0, 1.0),
            idle=(0.3, 0.3),
        )
        yield {"task": task, "fmt": fmt, "ns": ns, "q": q, "poses": poses, "bench": bench}


@pytest.mark.parametrize("kind", ["mcap", "sqlite3", "ros1"])
def test_bag_imports_byte_for_byte(tmp_path, arm, kind):
    fmt = arm["fmt"]
    bag = tmp_path / ("rec.bag" if kind == "ros1" else "rec")
    arm["bench"].write_bag(
        bag, arm["ns"], arm["q"], list(fmt.columns), arm["poses"], kind, np.random.default_rng(1)
    )
    header, table = recording_table(
        arm["ns"],
        arm["q"],
        arm["poses"],
        fmt.columns,
        fmt.env_names,
        env_columns(parse_env(ENV), fmt.env_names),
    )
    direct = write_recording(tmp_path / "direct" / "rec.csv", header, table)
    (out,) = import_bags([bag], "/joint_states", parse_env(ENV), tmp_path / "imported", fmt)
    assert out.name == "rec.csv" and filecmp.cmp(out, direct, shallow=False)
    rec = read_recording(out, fmt)
    assert np.array_equal(rec.values, arm["q"])  # the shuffled JointState names mapped back by name
    assert rec.env_rows.shape == (arm["q"].shape[0], 4) and rec.ignored == []


def test_missing_topic_or_joint_writes_nothing(tmp_path, arm, capsys):
    fmt = arm["fmt"]
    good = arm["bench"].write_bag(
        tmp_path / "good", arm["ns"], arm["q"], list(fmt.columns), arm["poses"], "mcap"
    )
    names = [c for c in fmt.columns if c != "panda_joint3"]
    keep = [i for i, c in enumerate(fmt.columns) if c != "panda_joint3"]
    three = arm["bench"].write_bag(
        tmp_path / "nojoint", arm["ns"], arm["q"][:, keep], names, arm["poses"], "mcap"
    )
    out = tmp_path / "out"
    with pytest.raises(
        ValueError, match=r"good: no topic '/nope' \(the bag has \['/can_pose', '/joint_states', "
    ):
        import_bags([good], "/joint_states", parse_env("can=/can_pose,goal=/nope"), out, fmt)
    with pytest.raises(
        ValueError,
        match=r"nojoint: topic '/joint_states' message 0 lacks the robot's joint\(s\) "
        r"\['panda_joint3'\]",
    ):
        import_bags([good, three], "/joint_states", parse_env(ENV), out, fmt)
    assert (
        not out.exists()
    )  # the good bag was read, but nothing is written while another is refused
    with pytest.raises(
        ValueError,
        match=r"nothing fills the environment column 'goal_x' .* give --env goal=/topic, "
        r"--env goal=tf:FRAME or --const goal_x=VALUE",
    ):
        import_bags([good], "/joint_states", parse_env("can=/can_pose"), out, fmt)
    assert main([str(good), "--joints", "/js", "--env", ENV, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err.startswith("error: ")
        and "no topic '/js'" in err
        and "\n" not in err
        and not out.exists()
    )
    assert main([str(good), "--joints", "/joint_states", "--env", ENV, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["good.csv", "good.import.json"]
