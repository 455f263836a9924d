"""Run time on an idle machine against the same machine with one other CPU-bound process, for
torch's thread settings side by side in one run (on demand: ``python
benchmarks/studies/contention.py
[--threads 1,default] [--envs 100]``).

Two workloads, each in a fresh Python process so no thread pool or cache carries over:

* ``experiment``: ``python -m protorch experiment=point_particle threads=N`` at a reduced budget:
  ``--envs`` loop environments (default 100) in batches of 50, PRO <= 50 iterations x 100
  samples (the experiment's sample and relevance sizes), 50 held-out environments, 10 moving
  episodes, the demos-only and RWR baselines, no figures.
* ``loop``: the README's library loop snippet (``self_improve`` with PRO on the point particle,
  30 x 3 synthetic demonstrations, beta 20, alpha 1e-3) at ``--envs`` environments, B = 50,
  PRO <= 50 iterations, with ``self_improve(..., LoopSettings(threads=N))``.

``busy`` starts ``python3 -c 'while True: pass'`` before the workload and stops it after. It
prints each wall time, busy / idle per thread setting (the goal: <= 2) and each setting's time
against ``--threads``' first entry under the same load. Run it on an otherwise quiet machine: on a
shared one the other users are load too, and the idle column is not idle.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

LOOP = """
import torch
from protorch import PRO, ProMP, make_env_map, self_improve, demonstration_dataset
from protorch.loop import LoopSettings, OptimizerSpec, Run
from protorch.tasks import PointParticleTask

task = PointParticleTask(objectives="clearance")
promp = ProMP(num_dof=2, num_basis=10, num_steps=100)
demos, demo_envs = task.demonstrations(30, per_env=3)
data = demonstration_dataset(promp, demos, demo_envs, task_name=task.name, var_floor=1e-4)
self_improve(task, promp, data,
             OptimizerSpec(PRO, dict(beta=20.0, num_samples=100, max_iter=50,
                                     relevance_samples=100, noise_floor=None)),
             lambda: make_env_map("torch", alpha=1e-3),
             LoopSettings(num_envs={envs}, batch_size=50, add_only="success", choice="random",
                          var_floor=1e-4, eval_dtype="float32", checkpoint_every=1,
                          refill=False, threads={threads}),
             Run(dir={run_dir!r}, resume=False, progress=False))
"""


def _command(workload: str, threads: str, envs: int, run_dir: str) -> list[str]:
    n = "null" if threads == "default" else threads
    if workload == "experiment":
        return [
            sys.executable,
            "-m",
            "protorch",
            "experiment=point_particle",
            f"threads={n}",
            "plot=false",
            f"settings.loop.num_envs={envs}",
            "settings.loop.batch_size=50",
            "optimizer.max_iter=50",
            "settings.test.num_envs=50",
            "settings.dynamic.episodes=10",
            "settings.progress=false",
            f"hydra.run.dir={run_dir}",
        ]
    loop_threads = {"null": "None", "auto": "'auto'"}.get(n, n)
    return [sys.executable, "-c", LOOP.format(threads=loop_threads, envs=envs, run_dir=run_dir)]


def timed(cmd: list[str], busy: bool) -> float:
    """Wall seconds of ``cmd``; with ``busy`` one spinning process runs alongside (then stopped)."""
    spinner = subprocess.Popen(["python3", "-c", "while True: pass"]) if busy else None
    try:
        time.sleep(0.5 if busy else 0.0)  # let the competitor get scheduled first
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True)
        return time.perf_counter() - t0
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--threads",
        default="auto,1,default",
        help="comma-separated settings: 'auto', ints or 'default' (torch's own)",
    )
    p.add_argument(
        "--envs", type=int, default=100, help="loop environments of both workloads (default 100)"
    )
    p.add_argument("--workloads", default="experiment,loop")
    args = p.parse_args()
    settings = args.threads.split(",")
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workload in args.workloads.split(","):
            for load in ("idle", "busy"):
                for threads in settings:  # back to back, so each pair sees the same other load
                    run_dir = str(Path(tmp) / f"{workload}_{load}_{threads}")
                    rows[workload, load, threads] = timed(
                        _command(workload, threads, args.envs, run_dir), load == "busy"
                    )
                    print(
                        f"{workload:10s} {load:4s} threads={threads:7s} "
                        f"{rows[workload, load, threads]:7.1f} s",
                        flush=True,
                    )
    print(
        "\n| workload | threads | idle [s] | busy [s] | busy / idle | idle vs threads="
        f"{settings[0]} "
        f"| busy vs threads={settings[0]} |\n|---|---|---|---|---|---|---|"
    )
    for workload in args.workloads.split(","):
        for t in settings:
            idle, busy = rows[workload, "idle", t], rows[workload, "busy", t]
            print(
                f"| {workload} | {t} | {idle:.1f} | {busy:.1f} | {busy / idle:.2f} | "
                f"{idle / rows[workload, 'idle', settings[0]]:.2f} | "
                f"{busy / rows[workload, 'busy', settings[0]]:.2f} |"
            )


if __name__ == "__main__":
    main()
