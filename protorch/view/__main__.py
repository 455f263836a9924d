"""``python -m protorch.view [RUN_DIR] [--host H] [--port P]`` (also ``protorch view ...``):
serve the live viewer of a trained ``point_particle`` or ``arm_reach`` run. Without ``RUN_DIR``
the newest such run under ``runs/`` is opened.

``python -m protorch.view --teach TASK [RUN_DIR] [--out FOLDER]``: the teach page, where
demonstrations of ``point_particle`` or ``arm_reach`` are drawn by hand and written to
``FOLDER`` for ``python -m protorch experiment=TASK task.demos=FOLDER``; with ``RUN_DIR`` (a
trained run of that task) the environments where its map fails are offered first.

``python -m protorch.view teleop RUN [--study N --conditions none,fixed,adaptive]``: drive the beam
of an ``experiment=teleop_window`` run through its moving window (:mod:`protorch.view.teleop`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from .scene import MAKE_RUN, build_task, find_runs, open_run, read_config
from .server import Viewer
from .teach import TeachSession, failing_envs
from .teach_server import Teacher
from .teach_tasks import TEACH_TASKS, make_teach_task
from .teleop_server import teleop_main

__all__ = ["main", "parse_args", "teach_session"]


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="protorch view", description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run directory (default: the newest under --runs)")
    ap.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    ap.add_argument(
        "--port", type=int, default=8080, help="port (default 8080; 0 picks a free one)"
    )
    ap.add_argument(
        "--runs", default="runs", help="where to look for runs without RUN_DIR (default runs/)"
    )
    ap.add_argument("--samples", type=int, default=16, help="sample paths drawn (default 16)")
    ap.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: one small query is fastest on one thread)",
    )
    teach = ap.add_argument_group("teaching (docs/teach.md)")
    teach.add_argument(
        "--teach", choices=TEACH_TASKS, help="serve the teach page for this task instead"
    )
    teach.add_argument(
        "--out",
        help="the demonstration folder written (default demos/TASK; continued if it exists)",
    )
    teach.add_argument(
        "--per-env", type=int, default=3, help="demonstrations per environment (default 3, >= 2)"
    )
    teach.add_argument(
        "--envs", type=int, help="environments to teach (default 30 point_particle, 20 arm_reach)"
    )
    teach.add_argument(
        "--steps",
        type=int,
        help="time steps a demonstration is resampled to (default: the run's "
        "promp.num_steps, else 100)",
    )
    teach.add_argument(
        "--format",
        default="out",
        choices=("out", "csv"),
        help="out: trajK.out / envK.out (default); csv: timestamped recordings demoK.csv "
        "(docs/recordings.md)",
    )
    teach.add_argument(
        "--seed", type=int, default=0, help="seed of the proposed environments (default 0)"
    )
    teach.add_argument(
        "--robot",
        help="arm_reach without RUN_DIR: a shipped robot (e.g. panda) or a yaml file of "
        "robot.* settings (docs/your_own_robot.md); default the Panda",
    )
    return ap.parse_args(argv)


def teach_session(args) -> tuple[TeachSession, object]:
    """The teach page's session (and the run, or ``None``) from the command line's arguments."""
    run = None if args.run_dir is None else open_run(args.run_dir)
    cfg = {} if run is None else read_config(run.run_dir)
    if run is not None and run.model.task_name != args.teach:
        raise ValueError(f"{args.run_dir} is a {run.model.task_name} run, not {args.teach}")
    robot = cfg.get("robot") if run is not None else _robot_arg(getattr(args, "robot", None))
    task = None if run is None and robot is None else build_task(args.teach, cfg.get("task"), robot)
    teach = make_teach_task(args.teach, task)
    steps = args.steps or (100 if run is None else run.model.promp.num_steps)
    num_envs = args.envs or teach.default_envs
    proposals = None
    if run is not None:  # random environments, those where the run's map fails first
        proposals = failing_envs(
            run, teach.sample_envs(4 * num_envs + 16, torch.Generator().manual_seed(args.seed))
        )
    session = TeachSession(
        teach,
        Path(args.out or f"demos/{args.teach}"),
        per_env=args.per_env,
        num_envs=num_envs,
        num_steps=int(steps),
        proposals=proposals,
        seed=args.seed,
        fmt=args.format,
    )
    return session, run


def _robot_arg(value: str | None):
    """``--robot``: a shipped name, or a yaml file of ``robot.*`` settings (read here)."""
    if value is None or not value.endswith((".yaml", ".yml")):
        return value
    import yaml

    path = Path(value)
    if not path.is_file():
        raise FileNotFoundError(f"--robot {value}: no such file")
    return dict(yaml.safe_load(path.read_text()) or {})


def _serve(make, what: str) -> int:
    server = make()
    print(f"protorch view: {what} at {server.url}  (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.close()
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["teleop"]:  # the teleoperation page (protorch.view.teleop_server)
        return teleop_main(argv[1:])
    args = parse_args(argv)
    torch.set_num_threads(max(1, args.threads))
    if args.teach is not None:
        try:
            session, run = teach_session(args)
        except (FileNotFoundError, ValueError) as exc:
            print(f"protorch view --teach: {exc}", file=sys.stderr)
            return 1
        code = _serve(
            lambda: Teacher(session, run=run, host=args.host, port=args.port),
            f"teaching {args.teach} into {session.folder.resolve()}",
        )
        p = session.progress()
        print(
            f"kept {p['kept']} demonstrations ({p['marked']} marked), {p['envs_done']} "
            "environments complete; "
            f"train with: python -m protorch experiment={args.teach} task.demos={session.folder}"
        )
        return code
    if args.run_dir is None:
        runs = find_runs(args.runs)
        if not runs:
            print(
                f"no point_particle or arm_reach run under {Path(args.runs).resolve()}; make one "
                f"with: {MAKE_RUN}"
            )
            return 1
        args.run_dir = runs[0]
    try:
        run = open_run(args.run_dir)
    except (FileNotFoundError, ValueError) as exc:
        print(f"protorch view: {exc}", file=sys.stderr)
        return 1
    return _serve(
        lambda: Viewer(run, host=args.host, port=args.port, num_samples=args.samples),
        f"{run.model.task_name} run {Path(args.run_dir).resolve()}",
    )


if __name__ == "__main__":
    sys.exit(main())
