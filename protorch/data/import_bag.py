"""ROS bags in: timestamped recordings (:mod:`protorch.data.recordings`), one per bag or per
segment.

    python -m protorch.data.import_bag BAG [BAG ...] --joints /joint_states \\
        [--env can=/can_pose,goal=tf:target] [--const goal_x=0.7,goal_y=0] --out FOLDER \\
        [--task arm_reach] [--stamp auto|header|log] [--frame ROOT] [--split idle [--idle 2]]

Reads ROS 1 bags (``.bag``) and ROS 2 bags (a folder with ``metadata.yaml``; sqlite3 or MCAP
storage) through ``rosbags`` (pure Python, no ROS installation; ``pip install
"protorch[recordings]"``).
``--joints`` is a ``sensor_msgs/JointState`` topic: its ``name`` list is mapped to the robot's
joints by name (any order; other joints such as a gripper's are ignored; missing joints are an
error naming them). ``--env NAME=TOPIC,...`` fills the task's environment columns ``NAME_x``,
``NAME_y`` (and ``NAME_z`` where the task has one) from the position of a
``geometry_msgs/PoseStamped`` (or ``Pose``, ``PointStamped``, ``Point``, ``TransformStamped``)
topic; ``NAME=tf:FRAME`` from the ``/tf`` and ``/tf_static`` transforms of ``child_frame_id``
``FRAME``, composed up to the top of its tree or to ``--frame ROOT`` (:mod:`protorch.data.bag_tf`).
Either is held from each message to the next onto the joints' time stamps (before the first
message: its first value). ``--const can_x=0.56,...`` sets columns no topic gives.

Time (:mod:`protorch.data.bag_stamps`): ``--stamp auto`` reads the header stamps, the bag's
receive times for a topic whose header stamps are zero and for all topics when one topic's
stamps do not overlap the joints' (a clock offset); stamps that step back by at most the
jitter tolerance are sorted, a larger step back is refused naming the message. In seconds from
the first joint message (of the segment). ``--split idle`` cuts a bag holding several
demonstrations at idle periods of ``--idle`` seconds (:func:`~protorch.data.cleaning.split_idle`):
``BAG_1.csv``, ``BAG_2.csv``, ...

Every bag is read and checked (the topics, the joint names, the stamps, the table as the
recordings reader checks it: time order, NaN, joint limits) before the first file is written;
each file is written atomically as ``FOLDER/<bag name>.csv`` with the import's report beside it
(``<bag name>.import.json``: the clock used and why, what was sorted, the environment's sources).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..tasks.arm.demos import arm_demo_format
from ..tasks.arm.reach import ArmReachTask
from .bag_stamps import JITTER, Stream, describe, resolve_stamps
from .bag_tf import TF_STATIC, TF_TOPIC, chain, compose, edge_stream, tf_edges
from .cleaning import split_idle
from .files import atomic_write_bytes
from .quality import STREAM_END_S
from .recordings import IMPORT_SUFFIX, TIME, check_table, write_recording

__all__ = ["import_bags", "main", "parse_const", "parse_env", "read_bag", "recording_table"]

_POSITION_TYPES = ("PoseStamped", "Pose", "PointStamped", "Point", "TransformStamped")
TF = "tf:"  # --env NAME=tf:FRAME
_JOINTS = "joints"  # the joints' stream among a bag's streams


def parse_env(spec: str | None) -> dict[str, str]:
    """``"can=/can_pose,goal=tf:target"`` -> ``{"can": "/can_pose", "goal": "tf:target"}``."""
    out: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in (spec or "").split(","))):
        name, eq, topic = part.partition("=")
        if not eq or not name.strip() or not topic.strip() or topic.strip() == TF:
            raise ValueError(f"--env: expected NAME=TOPIC or NAME=tf:FRAME[,...], got {part!r}")
        out[name.strip()] = topic.strip()
    return out


def parse_const(spec: str | None, env_names: Sequence[str]) -> dict[str, float]:
    """``"can_x=0.56,can_y=0"`` -> ``{"can_x": 0.56, "can_y": 0.0}``; each name one of the task's
    environment columns ``env_names``."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in (spec or "").split(","))):
        name, eq, value = (x.strip() for x in part.partition("="))
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not eq or not np.isfinite(v):
            raise ValueError(f"--const: expected COLUMN=NUMBER[,...], got {part!r}")
        if name not in env_names:
            raise ValueError(
                f"--const {name}=...: not an environment column of the task ({list(env_names)})"
            )
        out[name] = v
    return out


def env_columns(
    env_topics: dict[str, str], env_names: Sequence[str], consts: dict[str, float] | None = None
) -> dict[str, tuple[str, int]]:
    """Each environment column of the task no ``--const`` sets -> ``(pose name, axis)``; a
    column nothing fills, one filled twice, or a name that fills none is an error naming it."""
    consts = consts or {}
    cols: dict[str, tuple[str, int]] = {}
    for col in env_names:
        stem, _, axis = col.rpartition("_")
        if stem in env_topics and axis in ("x", "y", "z"):
            if col in consts:
                raise ValueError(f"{col} is both --const {col}=... and --env {stem}=...: give one")
            cols[col] = (stem, "xyz".index(axis))
    missing = [c for c in env_names if c not in cols and c not in consts]
    if missing:
        stem = missing[0].rpartition("_")[0]
        raise ValueError(
            f"nothing fills the environment column {missing[0]!r} of the task (its environment: "
            f"{list(env_names)}); give --env {stem}=/topic, --env {stem}=tf:FRAME or "
            f"--const {missing[0]}=VALUE"
        )
    unused = [n for n in env_topics if not any(s == n for s, _ in cols.values())]
    if unused:
        raise ValueError(
            f"--env {unused[0]}=...: the task has no column {unused[0]}_x / {unused[0]}_y "
            f"(its environment: {list(env_names)})"
        )
    return cols


def recording_table(
    joint_ns: np.ndarray,
    q: np.ndarray,
    poses: dict[str, tuple[np.ndarray, np.ndarray]],
    joint_names: Sequence[str],
    env_names: Sequence[str],
    cols: dict[str, tuple[str, int]],
    consts: dict[str, float] | None = None,
):
    """The recording's ``(header, table (T, C))``: ``time`` (seconds from the first joint
    sample), the joints ``q (T, D)`` at ``joint_ns (T,)`` (int64 ns), each environment column
    held from the pose samples ``poses[name] = (ns (P,), xyz (P, 3))`` or set by ``consts``."""
    t = (joint_ns - joint_ns[0]).astype(np.float64) / 1e9  # (T,)
    env = np.empty((t.size, len(env_names)))  # (T, E)
    for c, col in enumerate(env_names):
        if col in (consts or {}):
            env[:, c] = consts[col]
            continue
        name, axis = cols[col]
        ns, xyz = poses[name]
        at = np.clip(
            np.searchsorted(ns, joint_ns, side="right") - 1, 0, ns.size - 1
        )  # the latest pose
        env[:, c] = xyz[at, axis]
    return [TIME, *joint_names, *env_names], np.concatenate([t[:, None], q, env], 1)


def _header_ns(msg) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        return 0
    stamp = header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(
        getattr(stamp, "nanosec", getattr(stamp, "nsec", 0))
    )


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


def _open(bag: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not bag.exists():
        raise FileNotFoundError(f"{bag}: no such bag")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags' errors vary by format
        raise ValueError(f"{bag}: not a readable ROS 1 or ROS 2 bag ({exc})") from None
    return reader


def _connections(
    reader, bag: Path, joints_topic: str, env_topics: dict[str, str]
) -> dict[str, list]:
    have = sorted({c.topic for c in reader.connections})
    conns = {}
    tf_wanted = any(t.startswith(TF) for t in env_topics.values())
    for topic in [joints_topic] + [t for t in env_topics.values() if not t.startswith(TF)]:
        found = [c for c in reader.connections if c.topic == topic]
        if not found:
            raise ValueError(f"{bag}: no topic {topic!r} (the bag has {have})")
        conns[topic] = found
    for topic in (TF_TOPIC, TF_STATIC):
        conns[topic] = [c for c in reader.connections if c.topic == topic] if tf_wanted else []
    if tf_wanted and not conns[TF_TOPIC] + conns[TF_STATIC]:
        raise ValueError(
            f"{bag}: no topic {TF_TOPIC!r} or {TF_STATIC!r} for the tf: poses (the bag has {have})"
        )
    if not all(c.msgtype.endswith("/JointState") for c in conns[joints_topic]):
        raise ValueError(
            f"{bag}: topic {joints_topic!r} is {conns[joints_topic][0].msgtype}, "
            "not sensor_msgs/JointState"
        )
    for name, topic in env_topics.items():
        if topic.startswith(TF):
            continue
        if not all(c.msgtype.rsplit("/", 1)[-1] in _POSITION_TYPES for c in conns[topic]):
            raise ValueError(
                f"{bag}: topic {topic!r} ({name}=) is {conns[topic][0].msgtype}, not one of "
                f"{', '.join(_POSITION_TYPES)}; for poses on {TF_TOPIC} give {name}=tf:FRAME"
            )
    for topic in (TF_TOPIC, TF_STATIC):
        bad = [c for c in conns.get(topic, []) if not c.msgtype.endswith("/TFMessage")]
        if bad:
            raise ValueError(f"{bag}: topic {topic!r} is {bad[0].msgtype}, not tf2_msgs/TFMessage")
    return conns


def _joint_stream(reader, conns, bag: Path, topic: str, joint_names: Sequence[str]) -> Stream:
    header, log, rows, order, names_seen = [], [], [], None, None
    for conn, log_ns, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        names = list(msg.name)
        if names != names_seen:
            missing = [j for j in joint_names if j not in names]
            if missing:
                raise ValueError(
                    f"{bag}: topic {topic!r} message {len(rows)} lacks the robot's joint(s) "
                    f"{missing} "
                    f"(its names: {names}; the robot's: {list(joint_names)})"
                )
            order, names_seen = [names.index(j) for j in joint_names], names
        pos = np.asarray(msg.position, dtype=np.float64)
        if pos.size != len(names):
            raise ValueError(
                f"{bag}: topic {topic!r} message {len(rows)} has {len(names)} names but "
                f"{pos.size} positions"
            )
        header.append(_header_ns(msg))
        log.append(int(log_ns))
        rows.append(pos[order])
    if len(rows) < 2:
        raise ValueError(
            f"{bag}: topic {topic!r} has {len(rows)} message(s); a recording needs >= 2"
        )
    return Stream(
        f"topic {topic!r}",
        np.asarray(header, dtype=np.int64),
        np.asarray(log, dtype=np.int64),
        np.stack(rows),
    )


def read_bag(
    bag: str | Path,
    joints_topic: str,
    env_topics: dict[str, str],
    joint_names: Sequence[str],
    *,
    stamp: str = "auto",
    root: str | None = None,
    jitter: float = JITTER,
):
    """Read one bag: ``(joint_ns (T,), q (T, D) in joint_names' order, {name: (ns (P,), xyz (P,
    3))},
    report)``, each stream in time order by the clock ``stamp`` chose
    (:func:`~protorch.data.bag_stamps.resolve_stamps`; the report says which and why). Errors
    (one line naming the bag and the topic, message or joint): a topic missing, a topic of
    another type, joints missing from a message, no messages, a stamp that steps back."""
    bag = Path(bag)
    reader = _open(bag)
    try:
        conns = _connections(reader, bag, joints_topic, env_topics)
        streams = {
            _JOINTS: _joint_stream(reader, conns[joints_topic], bag, joints_topic, joint_names)
        }
        for name, topic in env_topics.items():
            if topic.startswith(TF):
                continue
            header, log, xyz = [], [], []
            for conn, log_ns, raw in reader.messages(connections=conns[topic]):
                msg = reader.deserialize(raw, conn.msgtype)
                header.append(_header_ns(msg))
                log.append(int(log_ns))
                xyz.append(_position(msg))
            if not xyz:
                raise ValueError(f"{bag}: topic {topic!r} ({name}=) has no messages")
            streams[name] = Stream(
                f"topic {topic!r}",
                np.asarray(header, dtype=np.int64),
                np.asarray(log, dtype=np.int64),
                np.asarray(xyz, dtype=np.float64),
            )
        chains, static = {}, {}
        if conns[TF_TOPIC] or conns[TF_STATIC]:
            read = lambda cs: (
                tf_edges(
                    (log_ns, reader.deserialize(raw, c.msgtype))
                    for c, log_ns, raw in reader.messages(connections=cs)
                )
                if cs
                else {}
            )
            dynamic, static = read(conns[TF_TOPIC]), read(conns[TF_STATIC])
            for name, topic in env_topics.items():
                if topic.startswith(TF):
                    chains[name] = chain(topic[len(TF) :], dynamic, static, root, str(bag))
                    for e in chains[name]:
                        if e in dynamic:
                            streams[e] = edge_stream(e, dynamic[e])
    finally:
        reader.close()
    timed, report = resolve_stamps(streams, stamp, str(bag), jitter=jitter, reference=_JOINTS)
    joint_ns, q = timed[_JOINTS]
    poses = {n: timed[n] for n in env_topics if n not in chains}
    for name, edges in chains.items():
        poses[name] = compose(
            edges, {e: timed[e] for e in edges if e in timed}, static, int(joint_ns[0])
        )
    report["used"] = {streams[k].kind: v for k, v in report["used"].items()}
    report["reason"] = {
        ("all" if k == "all" else streams[k].kind): v for k, v in report["reason"].items()
    }
    report["sorted"] = {streams[k].kind: v for k, v in report["sorted"].items()}
    return joint_ns, q, poses, report


def _out_stem(bag: Path) -> str:
    return bag.stem if bag.is_file() else bag.name


def _env_report(poses, joint_ns, env_topics, consts) -> tuple[dict, list[str]]:
    """Where each environment column came from, each stream's first and last sample (seconds
    from the first joint sample), and a warning per stream that ends long before the joints."""
    out, warn = {"sources": {**env_topics, **consts}, "streams": {}}, []
    end = (joint_ns[-1] - joint_ns[0]) / 1e9
    for name, (ns, _) in poses.items():
        first, last = (ns[0] - joint_ns[0]) / 1e9, (ns[-1] - joint_ns[0]) / 1e9
        out["streams"][name] = {"first_s": float(first), "last_s": float(last)}
        if (
            ns.size > 1 and end - last > STREAM_END_S and end - last > 0.1 * end
        ):  # (static: one sample)
            warn.append(
                f"{name}'s stream ends at {last:.3f} s, {end - last:.3f} s before the joints' "
                "(held since)"
            )
    return out, warn


def import_bags(
    bags: Sequence[str | Path],
    joints_topic: str,
    env_topics: dict[str, str],
    out: str | Path,
    fmt,
    *,
    stamp: str = "auto",
    consts: dict[str, float] | None = None,
    root: str | None = None,
    jitter: float = JITTER,
    split: str | None = None,
    idle: float = 2.0,
    say: Callable[[str], None] | None = None,
) -> list[Path]:
    """Read and check every bag, then write its recordings into ``out`` (atomic files
    ``<bag name>.csv``, or ``<bag name>_K.csv`` per segment with ``split="idle"``, each with
    ``<name>.import.json``); nothing is written when any bag is refused. Returns the CSV files
    written. ``fmt``: the task's :class:`~protorch.data.demos.DemoFormat`; ``say``: called with
    one line per bag (the clock used, what was sorted, warnings)."""
    if stamp not in ("auto", "header", "log"):
        raise ValueError(f"--stamp must be auto, header or log, got {stamp!r}")
    if split not in (None, "idle"):
        raise ValueError(f"--split must be idle, got {split!r}")
    consts = dict(consts or {})
    cols = env_columns(env_topics, fmt.env_names, consts)
    stems = [_out_stem(Path(b)) for b in bags]
    dup = sorted({n for n in stems if stems.count(n) > 1})
    if dup:
        raise ValueError(f"two bags would both be written as {dup[0]}.csv: rename one")
    files = []
    for bag, stem in zip(bags, stems):
        joint_ns, q, poses, report = read_bag(
            bag, joints_topic, env_topics, fmt.columns, stamp=stamp, root=root, jitter=jitter
        )
        report["env"], warn = _env_report(poses, joint_ns, env_topics, consts)
        t = (joint_ns - joint_ns[0]) / 1e9
        segments = split_idle(t, q, idle) if split else [(0, joint_ns.size)]
        for k, (a, b) in enumerate(segments, 1):
            name = f"{stem}_{k}" if split else stem
            header, table = recording_table(
                joint_ns[a:b], q[a:b], poses, fmt.columns, fmt.env_names, cols, consts
            )
            check_table(
                f"{bag}" + (f" (segment {k})" if split else ""),
                header,
                table,
                fmt,
                row_name=f"topic {joints_topic} message",
                first_row=a,
            )
            rep = {"bag": Path(bag).name, **report, "warnings": warn}
            if split:
                rep["segment"] = {
                    "index": k,
                    "of": len(segments),
                    "start_s": float(t[a]),
                    "end_s": float(t[b - 1]),
                }
            files.append((name, header, table, rep))
        if say:
            seg = f"; split at idle into {len(segments)} recording(s)" if split else ""
            say(f"{bag}: {describe(report)}{seg}" + "".join(f"; warning: {w}" for w in warn))
    out = Path(out)
    written = []
    for name, header, table, rep in files:
        written.append(write_recording(out / f"{name}.csv", header, table))
        atomic_write_bytes(
            out / f"{name}{IMPORT_SUFFIX}", (json.dumps(rep, indent=1) + "\n").encode()
        )
    return written


def task_format(name: str):
    """The :class:`~protorch.data.demos.DemoFormat` of a task by name (its joints and limits read
    from the task)."""
    if name == ArmReachTask.name:  # (the task class's own name)
        return arm_demo_format(ArmReachTask())
    raise ValueError(f"--task: bags are imported for {ArmReachTask.name}, got {name!r}")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m protorch.data.import_bag", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument(
        "bags",
        nargs="+",
        metavar="BAG",
        help="ROS 1 .bag files or ROS 2 bag folders (sqlite3 or MCAP)",
    )
    ap.add_argument(
        "--joints", required=True, help="the sensor_msgs/JointState topic, e.g. /joint_states"
    )
    ap.add_argument(
        "--env",
        default="",
        help="NAME=TOPIC or NAME=tf:FRAME,... e.g. can=/can_pose,goal=tf:target",
    )
    ap.add_argument(
        "--const",
        default="",
        help="COLUMN=VALUE,... environment columns no topic gives, e.g. goal_x=0.7",
    )
    ap.add_argument(
        "--out", required=True, help="the recordings folder to write (task.demos=FOLDER)"
    )
    ap.add_argument(
        "--task",
        default=ArmReachTask.name,
        help=f"whose joints and environment (default {ArmReachTask.name})",
    )
    ap.add_argument(
        "--stamp",
        default="auto",
        choices=("auto", "header", "log"),
        help="time: header stamps where usable, else the bag's receive times (auto, the default); "
        "header stamps only; the bag's receive times only",
    )
    ap.add_argument(
        "--jitter",
        type=float,
        default=JITTER,
        help=f"seconds a stamp may step back and be sorted as jitter (default {JITTER:g})",
    )
    ap.add_argument(
        "--frame",
        default=None,
        help="the root frame of tf:FRAME poses (default: the top of its tree)",
    )
    ap.add_argument(
        "--split",
        default=None,
        choices=("idle",),
        help="several demonstrations per bag, cut at idle",
    )
    ap.add_argument(
        "--idle", type=float, default=2.0, help="seconds of rest that separate two demonstrations"
    )
    args = ap.parse_args(argv)
    try:
        fmt = task_format(args.task)
        written = import_bags(
            args.bags,
            args.joints,
            parse_env(args.env),
            args.out,
            fmt,
            stamp=args.stamp,
            consts=parse_const(args.const, fmt.env_names),
            root=args.frame,
            jitter=args.jitter,
            split=args.split,
            idle=args.idle,
            say=print,
        )
    except ImportError as exc:
        print(
            f'error: {exc}; install the recordings extra: pip install "protorch[recordings]"',
            file=sys.stderr,
        )
        return 2
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} recording(s) to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
