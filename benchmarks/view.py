"""Is the viewer live? Time from a changed environment parameter to the new mean and band sent,
side by side in one run (on demand: ``python benchmarks/view.py``; needs ``pip install -e
".[view]"``).

A synthetic arm run of the arm's data-set size (``--entries``, default 5000: 2004 priors + ~3000
learned entries in a full run; both classes, ``nearest_k = 30``, alpha 30 as the experiment) and a
point-particle run (``--pp-entries``, default 1000) are served by
:class:`protorch.view.server.Viewer`
on a free port with no browser attached (viser still encodes and queues every message). Each
repetition moves one coordinate by a small random step (``Viewer.set_env``, what a slider or a
drag calls) and records, from the change: the scene state (inference + trajectories + FK), the mean
and band sent, and the info panel (success check, costs) sent. Variants interleaved in one loop:
torch with 1 thread (the viewer's default) and with 2. Prints medians and 90th percentiles (ms)
of the wall-clock times and of the process's CPU time per change, and the machine's load average
(a busy machine inflates the wall-clock times; the CPU time much less).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

import torch
from _timing import Stopwatch

from protorch import ProMP, save_model
from protorch.data.dataset import TrajectoryDataset
from protorch.tasks import ArmReachTask, PointParticleTask
from protorch.view.scene import open_run
from protorch.view.server import Viewer


def arm_run(out: Path, entries: int, seed: int = 0) -> Path:
    """A synthetic arm run: ``entries`` random environments, each with the weights of the straight
    path to the nearest of 16 grid targets (by IK) plus noise, random side labels."""
    task = ArmReachTask()
    promp = ProMP(7, num_basis=10, num_steps=100)
    gen = torch.Generator().manual_seed(seed)
    goals = task.prior_grid(16)  # (16, 4)
    q, _ = task.ik_path(task.straight_paths(goals, promp.num_steps))  # (16, T, 7)
    w = promp.weights(q)  # (16, N)
    env = task.sample_envs(entries, gen)  # (M, 4)
    near = torch.cdist(env[:, 2:], goals[:, 2:]).argmin(1)  # (M,)
    mean = w[near] + 0.01 * torch.randn(entries, w.shape[1], generator=gen, dtype=torch.float64)
    ds = TrajectoryDataset(promp, 4, task_name=task.name)
    ds.append(
        env,
        mean,
        torch.full_like(mean, 1e-3),
        label=torch.randint(0, 2, (entries,), generator=gen),
        origin="prior",
        converged=True,
    )
    save_model(out, ds, backend="torch", alpha=30.0, nearest_k=30)
    return out


def particle_run(out: Path, entries: int, seed: int = 0) -> Path:
    """A synthetic point-particle run: ``entries`` random environments, each with the weights of a
    three-point path start -> hole -> goal."""
    task = PointParticleTask(objectives="clearance")
    promp = ProMP(2, num_basis=10, num_steps=100)
    env = task.sample_envs(entries, torch.Generator().manual_seed(seed))  # (M, 6)
    u = torch.linspace(0, 1, 100, dtype=torch.float64)[None, :, None]  # (1, T, 1)
    a, h, g = env[:, None, 0:2], env[:, None, 2:4], env[:, None, 4:6]  # (M, 1, 2)
    path = (
        (1 - u) ** 2 * a + 2 * u * (1 - u) * (2 * h - (a + g) / 2) + u**2 * g
    )  # (M, T, 2) through the hole
    mean = promp.weights(path)  # (M, N)
    ds = TrajectoryDataset(promp, 6, task_name=task.name)
    ds.append(env, mean, torch.full_like(mean, 1e-3), origin="prior", converged=True)
    save_model(out, ds, backend="torch", alpha=1e-3)
    (out / "config.yaml").write_text("name: point_particle\ntask:\n  objectives: clearance\n")
    return out


def measure(viewers: dict, threads: list[int], repeats: int, seed: int = 0) -> dict:
    """``{(name, threads): {"state_ms": [...], "sent_ms": [...], "info_ms": [...]}}``,
    interleaved."""
    gen = torch.Generator().manual_seed(seed)
    out = {
        (n, t): {"state_ms": [], "sent_ms": [], "info_ms": [], "cpu_ms": []}
        for n in viewers
        for t in threads
    }
    for r in range(repeats + 3):
        for name, v in viewers.items():
            for t in threads:
                torch.set_num_threads(t)
                env = v.env.clone()
                i = int(torch.randint(len(env), (1,), generator=gen))
                p = v.run.params[i]
                env[i] = env[i] + (p.hi - p.lo) * 0.01 * float(torch.randn(1, generator=gen))
                with Stopwatch() as sw:
                    v.set_env(env)
                cpu = 1e3 * sw.cpu
                if r >= 3:  # warm-up
                    for k, x in {**v.timings, "cpu_ms": cpu}.items():
                        out[(name, t)][k].append(x)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--entries", type=int, default=5000, help="arm map entries (default 5000)")
    ap.add_argument(
        "--pp-entries", type=int, default=1000, help="point-particle map entries (default 1000)"
    )
    ap.add_argument("--repeats", type=int, default=60)
    ap.add_argument(
        "--samples", type=int, default=16, help="sample paths drawn (the viewer's default 16)"
    )
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        runs = {
            "arm_reach": arm_run(Path(tmp) / "arm", args.entries),
            "point_particle": particle_run(Path(tmp) / "pp", args.pp_entries),
        }
        viewers = {
            n: Viewer(open_run(d), port=0, num_samples=args.samples) for n, d in runs.items()
        }
        try:
            res = measure(viewers, [1, 2], args.repeats)
        finally:
            for v in viewers.values():
                v.close()
    print(
        f"load average: {load0:.2f} before, {os.getloadavg()[0]:.2f} after (1 min), "
        f"{os.cpu_count()} CPUs; "
        f"{args.repeats} changes per row, {args.samples} sample paths"
    )
    print(
        f"{'run (map entries)':<26}{'threads':>8}{'state':>17}{'mean+band sent':>17}"
        f"{'info sent':>17}"
        f"{'CPU time':>17}"
    )
    for (name, t), d in res.items():
        m = viewers[name].run.model.env_map.num_points
        cells = []
        for k in ("state_ms", "sent_ms", "info_ms", "cpu_ms"):
            xs = sorted(d[k])
            cells.append(f"{statistics.median(xs):6.1f} / {xs[int(0.9 * (len(xs) - 1))]:5.1f}")
        print(f"{name + f' ({m})':<26}{t:>8}" + "".join(f"{c:>17}" for c in cells))
    print(
        "cells: median / 90th percentile, ms: wall clock from the change to the state, to the mean "
        "and band "
        "sent, to the info panel sent; CPU time of the process for the whole change (all threads)"
    )


if __name__ == "__main__":
    main()
