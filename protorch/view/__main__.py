"""``python -m protorch.view [RUN_DIR] [--host H] [--port P]`` (also ``protorch view ...``):
serve the live viewer of a trained ``point_particle`` or ``arm_reach`` run. Without ``RUN_DIR``
the newest such run under ``runs/`` is opened."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from .scene import MAKE_RUN, find_runs, open_run
from .server import Viewer

__all__ = ["main", "parse_args"]


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="protorch view", description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", nargs="?", help="a run directory (default: the newest under --runs)")
    ap.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 picks a free one)")
    ap.add_argument("--runs", default="runs", help="where to look for runs without RUN_DIR (default runs/)")
    ap.add_argument("--samples", type=int, default=16, help="sample paths drawn (default 16)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch CPU threads (default 1: one small query is fastest on one thread)")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.run_dir is None:
        runs = find_runs(args.runs)
        if not runs:
            print(f"no point_particle or arm_reach run under {Path(args.runs).resolve()}; make one with: {MAKE_RUN}")
            return 1
        args.run_dir = runs[0]
    torch.set_num_threads(max(1, args.threads))
    try:
        run = open_run(args.run_dir)
    except (FileNotFoundError, ValueError) as exc:
        print(f"protorch view: {exc}", file=sys.stderr)
        return 1
    viewer = Viewer(run, host=args.host, port=args.port, num_samples=args.samples)
    print(f"protorch view: {run.model.task_name} run {Path(args.run_dir).resolve()} at {viewer.url}  (Ctrl-C stops)",
          flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        viewer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
