"""Physics speed, side by side in one run (on demand: ``python benchmarks/physics.py``).

1. MuJoCo steps per second of the project's Panda scene (``protorch.sim.scene``): one ``MjData``
   stepped open loop in Python, a ``mujoco.batch.Batch`` of ``--episodes`` simulations stepped
   open loop, and the physics runner (``protorch.control.physics``: the reference, the
   computed-torque controller on its own batch, contacts and records every step) on
   ``--episodes`` straight reaches of the experiment's length (3 s + 1 s hold, 2000 steps of
   2 ms), for each thread count of ``--threads``.
2. With ``--run RUN_DIR`` (a finished ``experiment=arm_reach`` run): the run's own physics
   section timed again on its trained map, its held-out environments and its moving episodes
   (200 + 100 by default), for each thread count, and its share of that run
   (``metrics.json``: ``physics.seconds / seconds.total``, the renders apart).

The machine's load changes absolute times: compare the rows of one run.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch
from _timing import Stopwatch
from configs import arguments_of
from omegaconf import OmegaConf

from protorch.control.episodes import check_timing
from protorch.data.checkpoint import load
from protorch.experiments import check_config
from protorch.experiments.arm_physics import physics_section
from protorch.experiments.arm_reach import prepare
from protorch.primitives.promp import ProMP
from protorch.robots import load_robot

PANDA_MAX_ACCELERATION = load_robot("panda").max_acceleration
from protorch.control.physics import FixedMeans, run_physics_episodes
from protorch.sim.mj import load_mujoco
from protorch.sim.scene import build_scene, controller_model
from protorch.tasks import ArmReachTask


def open_loop(scene, n: int, steps: int, threads: int) -> tuple[float, float]:
    """Steps per second of one MjData in a Python loop and of a batch of ``n``."""
    mujoco = load_mujoco()
    q0 = scene.task.start_config().numpy()
    data = mujoco.MjData(scene.model)
    data.qpos[:] = q0
    with Stopwatch() as one:
        for _ in range(steps):
            mujoco.mj_step(scene.model, data)
    batch = mujoco.batch.Batch(scene.model, n, nthread=threads, persistent=True)
    batch.bind("qpos")[:] = q0
    with Stopwatch() as many:
        batch.step(nstep=steps)
    return steps / one.wall, n * steps / many.wall


def reaches(task: ArmReachTask, n: int) -> tuple[ProMP, torch.Tensor, torch.Tensor]:
    """``n`` straight reaches to random targets, the can out of the way: the ProMP, ``(n, N)``,
    ``(n, 4)``."""
    gen = torch.Generator().manual_seed(0)
    envs = task.sample_envs(n, gen)
    envs[:, 0], envs[:, 1] = 0.85, 0.45  # the can in the table's corner
    promp = ProMP(7, num_basis=10, num_steps=100, dtype=torch.float64)
    q, _ = task.ik_path(task.straight_paths(envs, 100))
    return promp, promp.weights(q), envs


def runner_rate(scene, ctrl, promp, w, envs, threads: int) -> tuple[float, float, dict]:
    timing = check_timing(0.02, 3.0, 1.0)
    walk = envs[:, None].expand(-1, timing.total + 1, -1)
    with Stopwatch() as sw:
        res = run_physics_episodes(
            scene,
            ctrl,
            FixedMeans(w),
            promp,
            timing,
            walk,
            kp=400.0,
            kd=40.0,
            ref_kp=10.0,
            max_acceleration=PANDA_MAX_ACCELERATION,
            threads=threads,
        )
    sec = sw.wall
    steps = envs.shape[0] * timing.total * round(timing.dt / scene.timestep)
    return steps / sec, sec, res.summary()


def run_section(run_dir: Path, threads: int) -> float:
    """Seconds of the physics section (no pictures) of a finished run, on its map and settings."""
    settings = check_config(
        OmegaConf.to_container(OmegaConf.load(run_dir / "config.yaml"), resolve=True)
    )
    exp = prepare(**arguments_of(prepare, settings))
    model = load(run_dir, device=exp.device, dtype=exp.dtype)
    torch.set_num_threads(threads)
    exp.moving_test(model)  # the kinematic episodes the physics test replays (not timed)
    with tempfile.TemporaryDirectory() as tmp:
        with Stopwatch() as sw:
            out = physics_section(exp, model, Path(tmp), plot=False)
        sec = sw.wall
    print(
        f"  {threads} thread(s): physics section {sec:.1f} s (test "
        f"{out['test']['success_rate']:.3f}, moving "
        f"{out.get('dynamic', {}).get('success_rate', float('nan')):.3f})"
    )
    return sec


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--episodes", type=int, default=300, help="simulations at once (default 300 = 200 + 100)"
    )
    p.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=[1, 2],
        help="thread counts to compare (default 1 2)",
    )
    p.add_argument(
        "--run",
        type=Path,
        default=None,
        help="a finished experiment=arm_reach run to time the section of",
    )
    p.add_argument(
        "--quick", action="store_true", help="20 episodes: a check that the benchmark runs"
    )
    a = p.parse_args()
    torch.set_num_threads(1)
    n = 20 if a.quick else a.episodes
    task = ArmReachTask(collision="volume")
    scene, ctrl = build_scene(task), controller_model(task)
    promp, w, envs = reaches(task, n)
    print(
        f"MuJoCo {load_mujoco().__version__}, the Panda scene ({scene.model.ngeom} geoms), "
        "timestep "
        f"{scene.timestep * 1e3:g} ms, {n} episodes of 4 s"
    )
    print(
        f"{'threads':>8}{'1 MjData, steps/s':>20}{'batch, steps/s':>17}{'runner, steps/s':>18}"
        f"{'runner s':>10}"
        f"{'success':>9}{'tracking rms':>14}"
    )
    for th in a.threads:
        single, batch = open_loop(scene, n, 400 if a.quick else 2000, th)
        rate, sec, s = runner_rate(scene, ctrl, promp, w, envs, th)
        print(
            f"{th:>8}{single:>20.0f}{batch:>17.0f}{rate:>18.0f}{sec:>10.1f}"
            f"{s['success_rate']:>9.3f}"
            f"{s['tracking_rms']:>14.2e}"
        )
    if a.run is not None:
        metrics = json.loads((a.run / "metrics.json").read_text())
        sec, phys = metrics.get("seconds", {}), metrics.get("physics", {})
        own = phys.get(
            "seconds", np.nan
        )  # the two tests and the episodes file (with the renders in older runs)
        print(
            f"\nthe run {a.run}: total {sec.get('total', np.nan):.1f} s, its physics section "
            f"{own:.1f} s "
            f"({100 * own / sec.get('total', np.nan):.1f} % of the run; held-out "
            f"{phys.get('test', {}).get('seconds', np.nan):.1f} s, moving "
            f"{phys.get('dynamic', {}).get('seconds', np.nan):.1f} s, "
            f"renders {phys.get('render_seconds', np.nan):.1f} s)"
        )
        for th in a.threads:
            run_section(a.run, th)


if __name__ == "__main__":
    main()
