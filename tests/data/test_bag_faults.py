"""Bags as labs record them (protorch.data.import_bag), written here with rosbags' own writers: a
clock
offset between topics, zero header stamps, header-stamp jitter, a backward jump that is not jitter,
poses
on /tf through a two-level tree (with /tf_static), constant environment columns, a motionless take,
a
session of two demonstrations split at idle, and bad input. Each test asserts the imported
values."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("rosbags")

from protorch.data.import_bag import import_bags, main, parse_const, parse_env
from protorch.data.recordings import read_recording, read_recordings
from protorch.tasks.arm.demos import arm_demo_format
from protorch.tasks.arm.reach import ArmReachTask

FMT = arm_demo_format(ArmReachTask())
JOINTS = list(FMT.columns)
REST = np.array([0.0, 0.0654, 0.0, -2.7266, 0.0, 2.7921, 0.7854])
T0 = 1_700_000_000_000_000_000  # ns
ENV = "can=/can_pose,goal=/target_pose"


def motion(t: np.ndarray) -> np.ndarray:
    """Joint angles ``(T, 7)`` at ``t (T,)`` seconds: at rest, 1.5 s of motion from 0.3
    s, at rest."""
    u = np.clip((t - 0.3) / 1.5, 0, 1)
    s = u**3 * (10 - 15 * u + 6 * u**2)
    return REST + np.outer(s, [0.4, 0.3, -0.2, 0.5, 0.1, -0.3, 0.2])


class Bag:
    """A bag's messages before writing: ``add(topic, type, log_ns, msg)``, then ``write(path,
    kind)``."""

    def __init__(self, kind: str = "mcap") -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.kind, self.ros1 = kind, kind == "ros1"
        self.ts = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            tf = get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
            self.ts.register(tf)
        self.T, self.msgs = self.ts.types, []

    def header(self, ns: int, frame: str = ""):
        stamp = self.T["builtin_interfaces/msg/Time"](sec=int(ns // 10**9), nanosec=int(ns % 10**9))
        extra = {"seq": 0} if self.ros1 else {}
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)

    def joints(self, log_ns, stamp_ns, q, names=JOINTS, topic="/joint_states"):
        js, empty = self.T["sensor_msgs/msg/JointState"], np.zeros(0)
        for lg, st, row in zip(log_ns, stamp_ns, q):
            self.msgs.append(
                (
                    topic,
                    js,
                    int(lg),
                    js(
                        header=self.header(int(st)),
                        name=list(names),
                        position=np.asarray(row, dtype=np.float64),
                        velocity=empty,
                        effort=empty,
                    ),
                )
            )

    def poses(self, topic, log_ns, stamp_ns, xyz):
        T = self.T
        for lg, st, p in zip(log_ns, stamp_ns, xyz):
            quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]), orientation=quat
            )
            msg = T["geometry_msgs/msg/PoseStamped"](
                header=self.header(int(st), "world"), pose=pose
            )
            self.msgs.append((topic, T["geometry_msgs/msg/PoseStamped"], int(lg), msg))

    def tf(self, topic, log_ns, parent, child, xyz, quat=(0.0, 0.0, 0.0, 1.0)):
        T = self.T
        for lg, p in zip(log_ns, xyz):
            tr = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](
                    x=float(p[0]), y=float(p[1]), z=float(p[2])
                ),
                rotation=T["geometry_msgs/msg/Quaternion"](
                    x=quat[0], y=quat[1], z=quat[2], w=quat[3]
                ),
            )
            ts_ = T["geometry_msgs/msg/TransformStamped"](
                header=self.header(int(lg), parent), child_frame_id=child, transform=tr
            )
            tf = T["tf2_msgs/msg/TFMessage"]
            self.msgs.append((topic, tf, int(lg), tf(transforms=[ts_])))

    def write(self, path):
        if self.ros1:
            from rosbags.rosbag1 import Writer

            writer, ser = Writer(path), self.ts.serialize_ros1
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if self.kind == "mcap" else StoragePlugin.SQLITE3
            writer, ser = Writer(path, version=8, storage_plugin=plugin), self.ts.serialize_cdr
        with writer:
            conns = {}
            for topic, typ, log_ns, msg in sorted(self.msgs, key=lambda m: m[2]):
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, typ.__msgtype__, typestore=self.ts)
                writer.write(conns[topic], log_ns, ser(msg, typ.__msgtype__))
        return path


def take(kind="mcap", seconds=2.1, rate=100, env_rate=50):
    """A bag of one motion: joints at ``rate`` Hz (log times 0.3 ms after the stamps), the can
    moving 1 mm per message along x and the target at ``env_rate`` Hz. Returns the bag (unwritten),
    the joints' stamps and angles, the can's and target's stamps and positions."""
    bag = Bag(kind)
    ns = T0 + np.arange(int(seconds * rate)) * (10**9 // rate)
    q = motion((ns - T0) / 1e9)
    m_ns = T0 - 5_000_000 + np.arange(int(seconds * env_rate) + 1) * (10**9 // env_rate)
    can = np.stack(
        [0.5 + 1e-3 * np.arange(m_ns.size), np.full(m_ns.size, 0.05), np.zeros(m_ns.size)], 1
    )
    goal = np.tile([0.7, -0.1, 0.0], (m_ns.size, 1))
    return bag, ns, q, m_ns, can, goal


def held(at_ns, ns, values):
    return values[np.clip(np.searchsorted(ns, at_ns, side="right") - 1, 0, ns.size - 1)]


def imported(tmp_path, name="b", **kw):
    (csv,) = import_bags(
        [tmp_path / name],
        "/joint_states",
        parse_env(kw.pop("env", ENV)),
        tmp_path / "out",
        FMT,
        **kw,
    )
    return read_recording(csv, FMT), json.loads(
        csv.with_name(csv.stem + ".import.json").read_text()
    )


def test_clock_offset_reads_receive_times(tmp_path):
    """Joint header stamps one hour ahead of the motion capture's: auto reads the bag's receive
    times for every topic (the can's 105 distinct positions, not one frozen)."""
    bag, ns, q, m_ns, can, goal = take()
    log = ns + 300_000
    bag.joints(log, ns + 3600 * 10**9, q)
    bag.poses("/can_pose", m_ns + 1_000_000, m_ns, can)
    bag.poses("/target_pose", m_ns + 1_000_000, m_ns, goal)
    bag.write(tmp_path / "b")
    rec, rep = imported(tmp_path)
    assert rep["used"] == dict.fromkeys(
        ["topic '/joint_states'", "topic '/can_pose'", "topic '/target_pose'"], "log"
    )
    assert "clock offset" in rep["reason"]["all"] and "-3600" in rep["reason"]["all"]
    np.testing.assert_array_equal(rec.time, (log - log[0]) / 1e9)
    np.testing.assert_array_equal(rec.env_rows[:, 0], held(log, m_ns + 1_000_000, can[:, 0]))
    assert np.unique(rec.env_rows[:, 0]).size == 105 and np.array_equal(rec.values, q)
    rec_h, rep_h = imported(tmp_path, stamp="header")  # as before: the can frozen at its last pose
    assert (
        rep_h["used"]["topic '/joint_states'"] == "header"
        and np.unique(rec_h.env_rows[:, 0]).size == 1
    )


def test_zero_header_stamps_read_receive_times(tmp_path):
    bag, ns, q, m_ns, can, goal = take("sqlite3")
    log = ns + 300_000
    bag.joints(log, np.zeros_like(ns), q)
    bag.poses("/can_pose", m_ns + 1_000_000, m_ns, can)
    bag.poses("/target_pose", m_ns + 1_000_000, m_ns, goal)
    bag.write(tmp_path / "b")
    rec, rep = imported(tmp_path)
    assert rep["used"] == {
        "topic '/joint_states'": "log",
        "topic '/can_pose'": "header",
        "topic '/target_pose'": "header",
    }
    assert rep["reason"] == {
        "topic '/joint_states'": f"{ns.size} of {ns.size} header stamps are zero"
    }
    np.testing.assert_array_equal(rec.time, (log - log[0]) / 1e9)
    np.testing.assert_array_equal(
        rec.env_rows[:, 0], held(log, m_ns, can[:, 0])
    )  # the can by its header stamps
    with pytest.raises(
        ValueError,
        match=r"b: topic '/joint_states' message 0 has a zero header stamp; --stamp auto",
    ):
        imported(tmp_path, stamp="header")


def test_jitter_is_sorted_and_a_jump_back_refused(tmp_path):
    """4 ms of header-stamp jitter at 250 Hz (messages logged in arrival order): sorted by stamp,
    the rows follow their stamps. A stamp 0.3 s back is refused naming the message, with the
    hint."""
    bag, ns, q, m_ns, can, goal = take(rate=250)
    rng = np.random.default_rng(0)
    stamp = ns + rng.integers(
        -4_000_000, 4_000_000, ns.size
    )  # +-4 ms on a 4 ms period: out of order
    bag.joints(ns + 5_000_000, stamp, q)
    bag.poses("/can_pose", m_ns + 1_000_000, m_ns, can)
    bag.poses("/target_pose", m_ns + 1_000_000, m_ns, goal)
    bag.write(tmp_path / "b")
    rec, rep = imported(tmp_path)
    order = np.argsort(stamp, kind="stable")
    assert not np.all(np.diff(stamp) > 0) and rep["sorted"]["topic '/joint_states'"]["count"] > 0
    assert rep["sorted"]["topic '/joint_states'"]["largest_s"] <= 0.008
    np.testing.assert_array_equal(rec.time, (stamp[order] - stamp[order][0]) / 1e9)
    np.testing.assert_array_equal(rec.values, q[order])
    bad = take()
    stamp = bad[1].copy()
    stamp[120] -= 300_000_000  # 0.3 s back: not jitter
    bad[0].joints(bad[1] + 300_000, stamp, bad[2])
    bad[0].poses("/can_pose", m_ns, m_ns, can)
    bad[0].poses("/target_pose", m_ns, m_ns, goal)
    bad[0].write(tmp_path / "jump")
    with pytest.raises(
        ValueError,
        match=r"jump: topic '/joint_states' message 120: stamp steps back 0\.29 s below "
        r"message 119's, more than the jitter tolerance 0\.05 s \(not jitter\); "
        r"the bag's receive times: --stamp log",
    ):
        imported(tmp_path, "jump")
    assert not (tmp_path / "out" / "jump.csv").exists()
    rec, rep = imported(tmp_path, "jump", stamp="log")
    np.testing.assert_array_equal(rec.time, (bad[1] - bad[1][0]) / 1e9)


def test_poses_on_tf_two_levels(tmp_path):
    """world -> table on /tf_static (0.5, -0.2, 0; turned 90 degrees about z), table -> can on /tf
    (0.3 + 1 mm per message, 0, 0) in a ROS 1 bag: the can in world is (0.5, -0.2 + 0.3 + ...);
    ``--frame table`` gives the can in the table's frame."""
    bag, ns, q, m_ns, _, goal = take("ros1")
    bag.joints(ns + 300_000, ns, q)
    bag.poses("/target_pose", m_ns + 1_000_000, m_ns, goal)
    half = np.sqrt(0.5)
    bag.tf(
        "/tf_static", [T0 - 10**9], "/world", "table", [(0.5, -0.2, 0.0)], (0.0, 0.0, half, half)
    )
    local = np.stack(
        [0.3 + 1e-3 * np.arange(m_ns.size), np.zeros(m_ns.size), np.zeros(m_ns.size)], 1
    )
    bag.tf("/tf", m_ns, "table", "can", local)
    bag.tf(
        "/tf_static", [T0 - 10**9], "world", "target", [(0.7, -0.1, 0.0)]
    )  # placed once: static only
    bag.write(tmp_path / "b.bag")
    (csv,) = import_bags(
        [tmp_path / "b.bag"],
        "/joint_states",
        parse_env("can=tf:can,goal=tf:target"),
        tmp_path / "out",
        FMT,
    )
    rec = read_recording(csv, FMT)
    assert np.array_equal(rec.env_rows[:, 2:], np.tile([0.7, -0.1], (ns.size, 1)))
    np.testing.assert_allclose(rec.env_rows[:, 0], 0.5, atol=1e-12)
    np.testing.assert_allclose(rec.env_rows[:, 1], -0.2 + held(ns, m_ns, local[:, 0]), atol=1e-12)
    (csv,) = import_bags(
        [tmp_path / "b.bag"],
        "/joint_states",
        parse_env("can=tf:can,goal=/target_pose"),
        tmp_path / "local",
        FMT,
        root="table",
    )
    np.testing.assert_allclose(
        read_recording(csv, FMT).env_rows[:, :2], held(ns, m_ns, local[:, :2]), atol=1e-12
    )
    with pytest.raises(
        ValueError,
        match=r"no transform on /tf or /tf_static has child_frame_id 'mug' "
        r"\(the frames: \['can', 'table', 'target', 'world'\]\)",
    ):
        import_bags(
            [tmp_path / "b.bag"],
            "/joint_states",
            parse_env("can=tf:mug,goal=/target_pose"),
            tmp_path / "x",
            FMT,
        )


def test_constants_alone_or_beside_topics(tmp_path):
    bag, ns, q, m_ns, can, _ = take()
    bag.joints(ns + 300_000, ns, q)
    bag.poses("/can_pose", m_ns, m_ns, can)
    bag.write(tmp_path / "b")
    consts = parse_const("can_x=0.56,can_y=0.0,goal_x=0.70,goal_y=0.0", FMT.env_names)
    rec, rep = imported(tmp_path, env="", consts=consts)
    assert np.array_equal(rec.env, [0.56, 0.0, 0.70, 0.0]) and np.ptp(rec.env_rows, 0).max() == 0
    assert rep["env"]["sources"] == consts and np.array_equal(rec.values, q)
    rec, _ = imported(tmp_path, env="can=/can_pose", consts={"goal_x": 0.7, "goal_y": -0.1})
    np.testing.assert_array_equal(rec.env_rows[:, 0], held(ns, m_ns, can[:, 0]))
    assert np.array_equal(rec.env_rows[:, 2:], np.tile([0.7, -0.1], (ns.size, 1)))
    with pytest.raises(
        ValueError, match=r"--const mug_x=\.\.\.: not an environment column of the task"
    ):
        parse_const("mug_x=1", FMT.env_names)
    with pytest.raises(
        ValueError, match=r"can_x is both --const can_x=\.\.\. and --env can=\.\.\.: give one"
    ):
        imported(tmp_path, env="can=/can_pose", consts={"can_x": 0.5, "goal_x": 0.7, "goal_y": 0.0})


def test_motionless_take_is_excluded(tmp_path):
    """Two takes that move and one that does not (joint range 1e-5 rad, as a real bag of an arm at
    rest): the folder trains on the two, the third listed with its reason."""
    for name, still in (("a", False), ("b", False), ("still", True)):
        bag, ns, q, *_ = take(seconds=2.5)
        if still:
            q = REST + 1e-5 * np.sin(np.arange(ns.size))[:, None]
        bag.joints(ns + 300_000, ns, q)
        bag.write(tmp_path / name)
    written = import_bags(
        [tmp_path / n for n in ("a", "b", "still")],
        "/joint_states",
        {},
        tmp_path / "out",
        FMT,
        consts=dict(zip(FMT.env_names, (0.56, 0.0, 0.7, 0.0))),
    )
    assert [p.name for p in written] == ["a.csv", "b.csv", "still.csv"]
    folder, _ = read_recordings(tmp_path / "out", FMT)
    rep = folder.report
    assert [f[0].name for f in folder.files] == ["a.csv", "b.csv"] and len(folder.demos) == 2
    assert rep["excluded"] == [
        {
            "file": "still.csv",
            "reason": "motionless: its joints span at most 2e-05 rad "
            "(panda_joint4), less than 0.02 rad",
        }
    ]
    assert rep["summary"][0].startswith("excluded still.csv: motionless")
    assert rep["recordings"][0]["import"]["used"]["topic '/joint_states'"] == "header"


def test_session_split_at_idle(tmp_path):
    """One bag, two demonstrations 3 s apart (at rest between them): two recordings, each the
    rows of its half (time from its own first row), cut in the middle of the rest."""
    bag = Bag("sqlite3")
    ns = T0 + np.arange(700) * 10_000_000  # 7 s at 100 Hz
    t = (ns - T0) / 1e9
    back = motion(np.full(1, 9.0)) - (
        motion(t - 3.5) - REST
    )  # from where the first ended back to rest
    q = np.where(
        t[:, None] < 3.5, motion(t), back
    )  # motions 0.3-1.8 s and 3.8-5.3 s, at rest between
    bag.joints(ns + 300_000, ns, q)
    bag.write(tmp_path / "session")
    written = import_bags(
        [tmp_path / "session"],
        "/joint_states",
        {},
        tmp_path / "out",
        FMT,
        split="idle",
        idle=1.0,
        consts=dict(zip(FMT.env_names, (0.56, 0.0, 0.7, 0.0))),
    )
    assert [p.name for p in written] == ["session_1.csv", "session_2.csv"]
    one, two = (read_recording(p, FMT) for p in written)
    cut = one.time.size
    assert 200 < cut < 380  # the rest between the motions: 1.8 s to 3.8 s
    np.testing.assert_array_equal(one.values, q[:cut])
    np.testing.assert_array_equal(two.values, q[cut:])
    np.testing.assert_allclose(two.time, t[cut:] - t[cut], atol=1e-12)
    rep = json.loads((tmp_path / "out" / "session_2.import.json").read_text())
    assert rep["segment"]["index"] == 2 and rep["segment"]["of"] == 2


def test_bad_input_names_the_problem_and_writes_nothing(tmp_path, capsys):
    bag, ns, q, m_ns, can, goal = take()
    bag.joints(ns + 300_000, ns, q)
    bag.joints(ns + 300_000, ns, q[:, :5], names=JOINTS[:2] + JOINTS[4:], topic="/five")
    bag.poses("/can_pose", m_ns, m_ns, can)
    bag.poses("/target_pose", m_ns, m_ns, goal)
    bag.write(tmp_path / "b")
    with pytest.raises(
        ValueError,
        match=r"topic '/five' \(can=\) is sensor_msgs/msg/JointState, not one of "
        r"PoseStamped, "
        r"Pose, PointStamped, Point, TransformStamped; for poses on /tf give can=tf:FRAME",
    ):
        imported(tmp_path, env="can=/five,goal=/target_pose")
    with pytest.raises(
        ValueError,
        match=r"topic '/five' message 0 lacks the robot's joint\(s\) \['panda_joint3', "
        r"'panda_joint4'\]",
    ):
        import_bags([tmp_path / "b"], "/five", parse_env(ENV), tmp_path / "out", FMT)
    assert (
        main(
            [
                str(tmp_path / "b"),
                "--joints",
                "/joint_states",
                "--env",
                "can=/can_pose",
                "--const",
                "goal_x=0.7",
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 2
    )
    assert "nothing fills the environment column 'goal_y'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert (
        main(
            [
                str(tmp_path / "b"),
                "--joints",
                "/joint_states",
                "--env",
                ENV,
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "time from header stamps (--stamp auto)" in printed and "wrote 1 recording(s)" in printed
