"""ROS bags in: one timestamped recording (:mod:`protorch.data.recordings`) per bag.

    python -m protorch.data.import_bag BAG [BAG ...] --joints /joint_states \\
        --env can=/can_pose,goal=/target_pose --out FOLDER [--task arm_reach] [--stamp header|log]

Reads ROS 1 bags (``.bag``) and ROS 2 bags (a folder with ``metadata.yaml``; sqlite3 or MCAP
storage) through ``rosbags`` (pure Python, no ROS installation; ``pip install "protorch[recordings]"``).
``--joints`` is a ``sensor_msgs/JointState`` topic: its ``name`` list is mapped to the robot's
joints by name (any order; other joints such as a gripper's are ignored; a missing joint is an
error naming it). ``--env NAME=TOPIC,...`` fills the task's environment columns ``NAME_x``,
``NAME_y`` (and ``NAME_z`` where the task has one) from the position of a
``geometry_msgs/PoseStamped`` (or ``Pose``, ``PointStamped``, ``Point``,
``TransformStamped``) topic, held from each message to the next onto the joints' time stamps
(before the first message: its first value). Time is the messages' header stamp (``--stamp
log``: the time the bag logged them), in seconds from the first joint message.

Every bag is read and checked (the topics, the joint names, the table as the recordings reader
checks it: time order, NaN, joint limits) before the first file is written; each file is written
atomically as ``FOLDER/<bag name>.csv``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..tasks.arm.demos import arm_demo_format
from ..tasks.arm.reach import ArmReachTask
from .recordings import TIME, check_table, write_recording

__all__ = ["import_bags", "main", "parse_env", "read_bag", "recording_table"]

_POSITION_TYPES = ("PoseStamped", "Pose", "PointStamped", "Point", "TransformStamped")


def parse_env(spec: str) -> dict[str, str]:
    """``"can=/can_pose,goal=/target_pose"`` -> ``{"can": "/can_pose", "goal": "/target_pose"}``."""
    out: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in (spec or "").split(","))):
        name, eq, topic = part.partition("=")
        if not eq or not name.strip() or not topic.strip():
            raise ValueError(f"--env: expected NAME=TOPIC[,NAME=TOPIC...], got {part!r}")
        out[name.strip()] = topic.strip()
    return out


def env_columns(env_topics: dict[str, str], env_names: Sequence[str]) -> dict[str, tuple[str, int]]:
    """Each environment column of the task -> ``(pose name, axis)``; a column no ``--env`` name
    fills, or a name that fills none, is an error naming it."""
    cols: dict[str, tuple[str, int]] = {}
    for col in env_names:
        stem, _, axis = col.rpartition("_")
        if stem in env_topics and axis in ("x", "y", "z"):
            cols[col] = (stem, "xyz".index(axis))
    missing = [c for c in env_names if c not in cols]
    if missing:
        raise ValueError(f"--env fills no column {missing[0]!r} of the task (its environment: {list(env_names)}); "
                         f"give e.g. {missing[0].rpartition('_')[0]}=/topic")
    unused = [n for n in env_topics if not any(s == n for s, _ in cols.values())]
    if unused:
        raise ValueError(f"--env {unused[0]}=...: the task has no column {unused[0]}_x / {unused[0]}_y "
                         f"(its environment: {list(env_names)})")
    return cols


def recording_table(joint_ns: np.ndarray, q: np.ndarray, poses: dict[str, tuple[np.ndarray, np.ndarray]],
                    joint_names: Sequence[str], env_names: Sequence[str], cols: dict[str, tuple[str, int]]):
    """The recording's ``(header, table (T, C))``: ``time`` (seconds from the first joint
    sample), the joints ``q (T, D)`` at ``joint_ns (T,)`` (int64 ns), and each environment
    column held from the pose samples ``poses[name] = (ns (P,), xyz (P, 3))``."""
    t = (joint_ns - joint_ns[0]).astype(np.float64) / 1e9  # (T,)
    env = np.empty((t.size, len(env_names)))  # (T, E)
    for c, col in enumerate(env_names):
        name, axis = cols[col]
        ns, xyz = poses[name]
        at = np.clip(np.searchsorted(ns, joint_ns, side="right") - 1, 0, ns.size - 1)  # the latest pose
        env[:, c] = xyz[at, axis]
    return [TIME, *joint_names, *env_names], np.concatenate([t[:, None], q, env], 1)


def _stamp(msg, log_ns: int, stamp: str) -> int:
    header = getattr(msg, "header", None)
    if stamp == "header" and header is not None:
        ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if ns > 0:
            return ns
    return int(log_ns)


def _position(msg) -> tuple[float, float, float]:
    for path in (("pose", "position"), ("position",), ("point",), ("transform", "translation"), ()):
        obj = msg
        try:
            for p in path:
                obj = getattr(obj, p)
            return float(obj.x), float(obj.y), float(obj.z)
        except AttributeError:
            continue
    raise ValueError(f"a {type(msg).__name__} has no position")


def read_bag(bag: str | Path, joints_topic: str, env_topics: dict[str, str], joint_names: Sequence[str],
             *, stamp: str = "header"):
    """Read one bag: ``(joint_ns (T,), q (T, D) in joint_names' order, {name: (ns (P,), xyz (P, 3))})``,
    messages in time order. Errors (one line naming the bag and the topic or joint): a topic
    missing, a topic of the wrong type, a joint missing from a message, no messages."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = Path(bag)
    if not bag.exists():
        raise FileNotFoundError(f"{bag}: no such bag")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags' errors vary by format
        raise ValueError(f"{bag}: not a readable ROS 1 or ROS 2 bag ({exc})") from None
    try:
        conns = {}
        have = sorted({c.topic for c in reader.connections})
        for topic in [joints_topic, *env_topics.values()]:
            found = [c for c in reader.connections if c.topic == topic]
            if not found:
                raise ValueError(f"{bag}: no topic {topic!r} (the bag has {have})")
            conns[topic] = found
        if not all(c.msgtype.endswith("/JointState") for c in conns[joints_topic]):
            raise ValueError(f"{bag}: topic {joints_topic!r} is {conns[joints_topic][0].msgtype}, not sensor_msgs/JointState")
        for name, topic in env_topics.items():
            if not all(c.msgtype.rsplit("/", 1)[-1] in _POSITION_TYPES for c in conns[topic]):
                raise ValueError(f"{bag}: topic {topic!r} ({name}=) is {conns[topic][0].msgtype}, not one of "
                                 f"{', '.join(_POSITION_TYPES)}")
        ns, rows, order, names_seen = [], [], None, None
        for conn, log_ns, raw in reader.messages(connections=conns[joints_topic]):
            msg = reader.deserialize(raw, conn.msgtype)
            names = list(msg.name)
            if names != names_seen:
                missing = [j for j in joint_names if j not in names]
                if missing:
                    raise ValueError(f"{bag}: topic {joints_topic!r} message {len(rows)} has no joint {missing[0]!r} "
                                     f"(its names: {names}; the robot's: {list(joint_names)})")
                order, names_seen = [names.index(j) for j in joint_names], names
            pos = np.asarray(msg.position, dtype=np.float64)
            if pos.size != len(names):
                raise ValueError(f"{bag}: topic {joints_topic!r} message {len(rows)} has {len(names)} names but "
                                 f"{pos.size} positions")
            ns.append(_stamp(msg, log_ns, stamp))
            rows.append(pos[order])
        if len(rows) < 2:
            raise ValueError(f"{bag}: topic {joints_topic!r} has {len(rows)} message(s); a recording needs >= 2")
        poses = {}
        for name, topic in env_topics.items():
            p_ns, xyz = [], []
            for conn, log_ns, raw in reader.messages(connections=conns[topic]):
                msg = reader.deserialize(raw, conn.msgtype)
                p_ns.append(_stamp(msg, log_ns, stamp))
                xyz.append(_position(msg))
            if not xyz:
                raise ValueError(f"{bag}: topic {topic!r} ({name}=) has no messages")
            p_ns = np.asarray(p_ns, dtype=np.int64)
            order_p = np.argsort(p_ns, kind="stable")
            poses[name] = (p_ns[order_p], np.asarray(xyz, dtype=np.float64)[order_p])
    finally:
        reader.close()
    return np.asarray(ns, dtype=np.int64), np.stack(rows), poses


def _out_name(bag: Path) -> str:
    return (bag.stem if bag.is_file() else bag.name) + ".csv"


def import_bags(bags: Sequence[str | Path], joints_topic: str, env_topics: dict[str, str], out: str | Path, fmt,
                *, stamp: str = "header") -> list[Path]:
    """Read and check every bag, then write one recording per bag into ``out`` (atomic files
    ``<bag name>.csv``); nothing is written when any bag is refused. Returns the files written.
    ``fmt``: the task's :class:`~protorch.data.demos.DemoFormat` (joint names, environment
    names, bounds)."""
    if stamp not in ("header", "log"):
        raise ValueError(f"--stamp must be header or log, got {stamp!r}")
    cols = env_columns(env_topics, fmt.env_names)
    names = [_out_name(Path(b)) for b in bags]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"two bags would both be written as {dup[0]}: rename one")
    tables = []
    for bag in bags:
        joint_ns, q, poses = read_bag(bag, joints_topic, env_topics, fmt.columns, stamp=stamp)
        header, table = recording_table(joint_ns, q, poses, fmt.columns, fmt.env_names, cols)
        check_table(str(bag), header, table, fmt, row_name=f"topic {joints_topic} message", first_row=0)
        tables.append((header, table))
    out = Path(out)
    return [write_recording(out / n, h, t) for n, (h, t) in zip(names, tables)]


def task_format(name: str):
    """The :class:`~protorch.data.demos.DemoFormat` of a task by name (its joints and limits read from the task)."""
    if name == "arm_reach":
        return arm_demo_format(ArmReachTask())
    raise ValueError(f"--task: bags are imported for arm_reach, got {name!r}")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m protorch.data.import_bag", description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="+", metavar="BAG", help="ROS 1 .bag files or ROS 2 bag folders (sqlite3 or MCAP)")
    ap.add_argument("--joints", required=True, help="the sensor_msgs/JointState topic, e.g. /joint_states")
    ap.add_argument("--env", required=True, help="NAME=TOPIC,... e.g. can=/can_pose,goal=/target_pose")
    ap.add_argument("--out", required=True, help="the recordings folder to write (task.demos=FOLDER)")
    ap.add_argument("--task", default="arm_reach", help="whose joints and environment (default arm_reach)")
    ap.add_argument("--stamp", default="header", choices=("header", "log"),
                    help="time: the messages' header stamps (default) or the bag's log times")
    args = ap.parse_args(argv)
    try:
        fmt = task_format(args.task)
        written = import_bags(args.bags, args.joints, parse_env(args.env), args.out, fmt, stamp=args.stamp)
    except ImportError as exc:
        print(f"error: {exc}; install the recordings extra: pip install \"protorch[recordings]\"", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} recording(s) to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
