"""Recordings as a robot logs them, made from the arm's synthetic demonstrations
(docs/recordings.md).

    python benchmarks/recordings.py --out DIR [--seed 0] [--bags] [--mixed] [--still]

The arm experiment's 20 x 3 synthetic demonstrations (``python -m protorch experiment=arm_reach``
draws the same with ``seed``) become 60 recordings, ``DIR/csv/demoNN.csv``:

- joint angles at 100, 500 or 1000 Hz (in turn), each interval jittered by +-10 %, time stamps in
  integer nanoseconds as ROS gives them;
- the motion stretched to 3-6 s at uneven speed (the phase runs at ``1 + a cos(2 pi u) + b cos(4 pi
  u)``,
  ``|a| + |b| <= 0.6``), idle ends of 0.3-1.5 s before and after;
- encoder noise (Gaussian, ``--encoder`` rad, default 2e-4), kept inside the joint limits;
- the can and the target at 120 Hz as motion capture reads them: the true positions plus a
  per-recording offset (Gaussian, ``--mocap`` m per axis, default 3 mm) plus per-sample noise
  (0.5 mm), held onto the joints' time stamps.

``--bags``: the same recordings as ROS bags, ``DIR/bags/demoNN`` (ROS 2; MCAP storage, every
fourth one sqlite3) and ``DIR/bags/demo00.bag`` (ROS 1) in place of ``demo00``: a
``/joint_states`` JointState with the names in another order than the robot's plus the two finger
joints, ``/can_pose`` and ``/target_pose`` PoseStamped. Imported with ``python -m
protorch.data.import_bag DIR/bags/* --joints /joint_states --env can=/can_pose,goal=/target_pose
--out DIR/imported``, the files equal ``DIR/csv``'s byte for byte (printed).

``--mixed``: the same 20 environments demonstrated as people do (:func:`mixed_demos`): every other
one once on the left and twice on the right, the others three times on one side; the same
demonstrations unrecorded in ``DIR/builtin`` (``trajK.out`` / ``envK.out``). ``--still``: also
``DIR/csv_still``, the recordings and a motionless one (:func:`add_motionless`).
"""

from __future__ import annotations

import argparse
import filecmp
from pathlib import Path

import numpy as np
import torch
from _timing import Stopwatch

from protorch.data.import_bag import env_columns, import_bags, recording_table
from protorch.data.recordings import write_recording
from protorch.experiments.loop_run import DEMO_SEED_OFFSET
from protorch.tasks.arm.demos import arm_demo_format
from protorch.tasks.arm.reach import ArmReachTask

RATES = (100, 500, 1000)
MOCAP_HZ = 120
FINGERS = ("panda_finger_joint1", "panda_finger_joint2")
POSES = {"can": "/can_pose", "goal": "/target_pose"}


def synthetic_demos(task, seed: int = 0, envs: int = 20, per_env: int = 3):
    """The arm experiment's synthetic demonstrations for ``seed`` (its ``make_demonstrations``):
    ``(demos [(T_i, 7)], envs (n, 4), labels (n,))``."""
    gen = torch.Generator().manual_seed(seed + DEMO_SEED_OFFSET)
    e = task.sample_envs(envs, gen, region="rectangles")
    return task.demonstrations(e, per_env, gen)


def mixed_demos(task, seed: int = 0, envs: int = 20, per_env: int = 3):
    """The same environments as :func:`synthetic_demos`, with the sides people give: every other
    environment demonstrated once on the left and ``per_env - 1`` times on the right, the others
    all on one side (alternating left, right): ``(demos [(T_i, 7)], envs (n, 4), labels (n,))``,
    the labels measured on the trajectories."""
    from protorch.tasks.arm.geometry import LEFT, RIGHT

    gen = torch.Generator().manual_seed(seed + DEMO_SEED_OFFSET)
    e = task.sample_envs(envs, gen, region="rectangles")  # (M, 4) as synthetic_demos draws them
    sides = []
    for k in range(envs):
        if k % 2 == 0:
            sides += [LEFT] + [RIGHT] * (per_env - 1)
        else:
            sides += [LEFT if k % 4 == 1 else RIGHT] * per_env
    return task.demonstrations(e.repeat_interleave(per_env, 0), 1, gen, sides=torch.tensor(sides))


def record(
    demo: np.ndarray,
    env: np.ndarray,
    rate: float,
    rng: np.random.Generator,
    lower,
    upper,
    *,
    encoder: float = 2e-4,
    mocap: float = 3e-3,
    mocap_row: float = 5e-4,
    duration=(3.0, 6.0),
    idle=(0.3, 1.5),
    speed: float = 0.6,
    pause: tuple[float, float] | None = None,
):
    """One recording of ``demo (T, D)`` in environment ``env (4,)`` (can x y, goal x y):
    ``(joint_ns (R,), q (R, D), poses {"can"|"goal": (ns (P,), xyz (P, 3))})``. ``pause``:
    ``(phase, seconds)`` the demonstrator stops at that phase for that long."""
    t_len = demo.shape[0]
    motion = rng.uniform(*duration)
    pre, post = rng.uniform(*idle), rng.uniform(*idle)
    a = rng.uniform(-speed, speed)
    b = rng.uniform(-1, 1) * (speed - abs(a))
    hold = pause[1] if pause else 0.0
    total = pre + motion + hold + post
    n = int(total * rate * 1.2) + 10
    dt_ns = np.round(1e9 / rate * (1 + rng.uniform(-0.1, 0.1, n))).astype(np.int64)
    t0_ns = 1_700_000_000_000_000_000 + int(rng.integers(0, 10**9))
    ns = t0_ns + np.concatenate([[0], np.cumsum(dt_ns)])
    ns = ns[ns - t0_ns <= total * 1e9]
    t = (ns - t0_ns) / 1e9
    u = np.clip((t - pre) / motion, 0, 1)  # the time fraction of the motion (before the pause)
    if pause:
        p_at = pause[0]
        # the pause: the motion's time fraction halts at p_at for `hold` seconds
        tm = t - pre
        tm = np.where(tm > p_at * motion + hold, tm - hold, np.minimum(tm, p_at * motion))
        u = np.clip(tm / motion, 0, 1)
    phase = (
        u + a * np.sin(2 * np.pi * u) / (2 * np.pi) + b * np.sin(4 * np.pi * u) / (4 * np.pi)
    )  # (R,) monotone
    idx = np.linspace(0, 1, t_len)
    q = np.stack([np.interp(phase, idx, demo[:, d]) for d in range(demo.shape[1])], 1)  # (R, D)
    q = np.clip(q + encoder * rng.standard_normal(q.shape), lower, upper)
    m_ns = (
        t0_ns
        - int(rng.integers(0, 10**7))
        + np.arange(0, int(total * MOCAP_HZ) + 2) * int(1e9 / MOCAP_HZ)
    )
    poses = {}
    for k, name in enumerate(("can", "goal")):
        true = np.array([env[2 * k], env[2 * k + 1], 0.0])
        off = np.array([*(mocap * rng.standard_normal(2)), 0.0])
        noise = mocap_row * rng.standard_normal((m_ns.size, 3))
        noise[:, 2] = 0
        poses[name] = (m_ns, true + off + noise)
    return ns, q, poses


def make_recordings(
    out: Path,
    seed: int = 0,
    *,
    encoder: float = 2e-4,
    mocap: float = 3e-3,
    bags: bool = False,
    count: int | None = None,
    mixed: bool = False,
) -> list[dict]:
    """Write ``out/csv`` (and with ``bags`` ``out/bags``): the 60 recordings (``mixed``: of
    :func:`mixed_demos`). Returns what each is."""
    task = ArmReachTask()
    fmt = arm_demo_format(task)
    demos, envs, labels = (mixed_demos if mixed else synthetic_demos)(task, seed)
    lower, upper = task.kinematics.lower.cpu().numpy(), task.kinematics.upper.cpu().numpy()
    cols = env_columns(POSES, fmt.env_names)
    rng = np.random.default_rng(seed)
    info = []
    n = len(demos) if count is None else int(count)
    for i in range(n):
        rate = RATES[i % len(RATES)]
        ns, q, poses = record(
            demos[i].numpy(), envs[i].numpy(), rate, rng, lower, upper, encoder=encoder, mocap=mocap
        )
        header, table = recording_table(ns, q, poses, fmt.columns, fmt.env_names, cols)
        write_recording(out / "csv" / f"demo{i:02d}.csv", header, table)
        kind = "ros1" if i == 0 else ("sqlite3" if i % 4 == 1 else "mcap")
        # the names' order drawn from its own generator: the same recordings with or without bags
        if bags:
            write_bag(
                out / "bags" / (f"demo{i:02d}.bag" if kind == "ros1" else f"demo{i:02d}"),
                ns,
                q,
                list(fmt.columns),
                poses,
                kind,
                np.random.default_rng([seed, i]),
            )
        info.append(
            {
                "file": f"demo{i:02d}.csv",
                "rate": rate,
                "rows": int(ns.size),
                "bag": kind,
                "label": int(labels[i]),
            }
        )
    return info


def add_motionless(src: Path, dst: Path, seed: int = 0) -> Path:
    """Copy the recordings folder ``src`` to ``dst`` and add ``demo60.csv``: the arm at rest for
    33 s at 30 Hz (988 rows, joint range about 1e-5 rad as in a real bag of an arm that never
    moved), in the environment of ``demo00.csv``. Returns the file added."""
    import shutil

    from protorch.data.recordings import read_recording

    task = ArmReachTask()
    fmt = arm_demo_format(task)
    shutil.copytree(src, dst, dirs_exist_ok=True)
    rest = task.start_config(torch.float64, "cpu").numpy()
    t = np.arange(988) / 30.0
    q = rest + 5e-6 * np.random.default_rng(seed + 54).standard_normal((t.size, rest.size))
    env = read_recording(src / "demo00.csv", fmt).env
    table = np.concatenate([t[:, None], q, np.broadcast_to(env, (t.size, env.size))], 1)
    return write_recording(dst / "demo60.csv", ["time", *fmt.columns, *fmt.env_names], table)


def write_bag(
    path: Path, joint_ns, q, joint_names, poses, kind: str, rng: np.random.Generator | None = None
) -> Path:
    """Write one recording as a bag (``kind``: ``mcap`` / ``sqlite3``: ROS 2, ``ros1``): the
    JointState names shuffled (``rng``) and the finger joints added; PoseStamped per pose."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    JointState, PoseStamped = T["sensor_msgs/msg/JointState"], T["geometry_msgs/msg/PoseStamped"]
    Pose, Point, Quat = (
        T["geometry_msgs/msg/Pose"],
        T["geometry_msgs/msg/Point"],
        T["geometry_msgs/msg/Quaternion"],
    )
    names = list(joint_names) + list(FINGERS)
    perm = (rng or np.random.default_rng(0)).permutation(len(names))

    def header(ns: int, frame: str):
        stamp = Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
        return (
            Header(seq=0, stamp=stamp, frame_id=frame)
            if ros1
            else Header(stamp=stamp, frame_id=frame)
        )

    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(
            path,
            version=8,
            storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3,
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    with writer:
        jc = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=ts)
        pc = {
            name: writer.add_connection(topic, PoseStamped.__msgtype__, typestore=ts)
            for name, topic in POSES.items()
        }
        msgs = []
        fingers = np.full((q.shape[0], len(FINGERS)), 0.04)
        full = np.concatenate([q, fingers], 1)[:, perm]
        empty = np.zeros(0)
        for k in range(q.shape[0]):
            m = JointState(
                header=header(int(joint_ns[k]), ""),
                name=[names[j] for j in perm],
                position=full[k].copy(),
                velocity=empty,
                effort=empty,
            )
            msgs.append(
                (int(joint_ns[k]) + 250_000, 0, jc, m)
            )  # logged 0.25 ms after it was stamped
        for name, (p_ns, xyz) in poses.items():
            for k in range(p_ns.size):
                pose = Pose(
                    position=Point(x=float(xyz[k, 0]), y=float(xyz[k, 1]), z=float(xyz[k, 2])),
                    orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                )
                msgs.append(
                    (
                        int(p_ns[k]) + 2_000_000,
                        1,
                        pc[name],
                        PoseStamped(header=header(int(p_ns[k]), "world"), pose=pose),
                    )
                )
        for log_ns, _, conn, m in sorted(msgs, key=lambda x: (x[0], x[1])):
            writer.write(conn, log_ns, serialize(m, m.__msgtype__))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--encoder", type=float, default=2e-4, help="encoder noise, rad")
    ap.add_argument(
        "--mocap", type=float, default=3e-3, help="per-recording motion-capture offset, m per axis"
    )
    ap.add_argument("--bags", action="store_true", help="also write the bags and import them")
    ap.add_argument(
        "--mixed",
        action="store_true",
        help="every other environment demonstrated once on the left and twice on the right",
    )
    ap.add_argument(
        "--still",
        action="store_true",
        help="also DIR/csv_still: the recordings and a motionless one",
    )
    args = ap.parse_args()
    with Stopwatch() as made:
        info = make_recordings(
            args.out,
            args.seed,
            encoder=args.encoder,
            mocap=args.mocap,
            bags=args.bags,
            mixed=args.mixed,
        )
    if args.mixed:  # the same IK demonstrations, not recorded: the authors' format
        from protorch.data.demos import write_demo

        demos, envs, _ = mixed_demos(ArmReachTask(), args.seed)
        for k, (d, e) in enumerate(zip(demos, envs)):
            write_demo(args.out / "builtin", k, d, e)
        print(f"wrote the same {len(demos)} demonstrations unrecorded to {args.out / 'builtin'}")
    if args.still:
        added = add_motionless(args.out / "csv", args.out / "csv_still", args.seed)
        print(
            f"copied {args.out / 'csv'} to {args.out / 'csv_still'} and added {added.name} "
            "(motionless)"
        )
    print(
        f"wrote {len(info)} recordings to {args.out / 'csv'} in {made.wall:.1f} "
        "s "
        f"(rows {min(i['rows'] for i in info)}-{max(i['rows'] for i in info)}; measured sides: "
        f"{sum(i['label'] == 0 for i in info)} left, {sum(i['label'] != 0 for i in info)} right)"
    )
    if args.bags:
        bags = sorted((args.out / "bags").iterdir())
        with Stopwatch() as imported:
            written = import_bags(
                bags, "/joint_states", POSES, args.out / "imported", arm_demo_format(ArmReachTask())
            )
        same = [filecmp.cmp(p, args.out / "csv" / p.name, shallow=False) for p in written]
        kinds = {k: sum(i["bag"] == k for i in info) for k in ("mcap", "sqlite3", "ros1")}
        print(
            f"imported {len(written)} bags ({kinds}) in {imported.wall:.1f} s; "
            "identical to the CSV "
            f"files: {sum(same)} of {len(same)}"
        )


if __name__ == "__main__":
    main()
