"""The moving test run through the policy: inline, the planner a control step behind
(deterministic), and the real planner thread, in kinematics and in MuJoCo (issue 53).

The episodes are the run's own moving test's: the environments of every instant of its kinematic
episodes, read from the run's ``physics/episodes.npz`` (the physics test replays the same ones),
its control step, velocity command and, for MuJoCo, its physics settings. Only what names the mean
to track changes: :func:`protorch.control.policy_episodes.run_policy_episodes` with the policy
``protorch.load(run)`` (``mode=inline``: the policy's own class choice at every control step;
``lagged``: each plan tracked ``--lag`` control steps after the inputs it was made from;
``thread``: ``planner="thread"``, the episode paced at real time, the newest plan of the planner
thread tracked). Printed per mode and plant: success rate, switches, the plan's age, and the run's
own numbers (``metrics.json``'s moving test: kinematics, and the physics test's ``dynamic``).

    python benchmarks/moving_thread.py RUN [RUN ...] [--modes inline,lagged,thread]
        [--plants kin,mujoco] [--episodes N] [--thread-episodes N] [--lag 1] [--json out.json]

``--follow reference --limits off,joint``: the arm's velocity command follows the policy's
reference (the tracker's plan mean plus continuity offset; kinematics: evaluated at the control
step, MuJoCo: at every physics step), without and with the robot's velocity, acceleration and jerk
limits (``joint``: ``JointwiseLimiter``, the two-rate policy's default; ``together``:
``JerkLimiter``, synchronised; ``on``: ``limits=True``, joint by joint). Printed with it:
``peaks``, over every tick of every episode, the reference's largest ``|qd| / max_velocity``,
``|qdd| / max_acceleration``, ``|jerk| / max_jerk`` (the acceleration's change over the tick),
``|q - q_last| / (tick max_velocity)`` and ``|qd - qd_last| / (tick max_acceleration)`` (the
robot's limits; the tick: the control step in kinematics, the physics step in MuJoCo), and the
episodes where one of them exceeds ``1 + 1e-9``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

import protorch
from protorch.control.episodes import check_timing
from protorch.control.policy_episodes import run_policy_episodes


def _run_setting(run: Path):
    from protorch.experiments.policy_run import rebuild_experiment
    from protorch.policy.load import read_config

    exp = rebuild_experiment(read_config(run / "config.yaml"), str(run))
    return exp.dyn_cfg, exp.physics_cfg


def _envs(run: Path, total: int) -> tuple[torch.Tensor, dict]:
    """The moving test's environments ``(E, T+1, 4)`` and the run's per-episode successes."""
    z = np.load(run / "physics" / "episodes.npz")
    mv = z["moving"]
    envs = np.concatenate([z["can"][mv], z["target"][mv]], -1)  # (E, T+1, 4)
    if envs.shape[1] != total + 1:
        raise ValueError(f"{run}: episodes of {envs.shape[1]} instants, the timing has {total + 1}")
    return torch.from_numpy(envs), {
        "kin": z["kinematic_success"][mv],
        "mujoco": z["success"][mv],
        "switched": (np.diff(z["labels"][mv], axis=1) != 0).any(1),  # in the run's MuJoCo test
    }


def _physics(task, pcfg: dict, dyn: dict, amax) -> dict:
    from protorch.sim.scene import build_scene, controller_model

    return dict(
        scene=build_scene(task, timestep=pcfg["timestep"]),
        ctrl_model=controller_model(task, timestep=pcfg["timestep"], mass_scale=pcfg["mass_scale"]),
        kp=pcfg["kp"],
        kd=pcfg["kd"],
        ref_kp=float(dyn.get("kp", 10.0)),
        max_acceleration=amax,
        threads=1,
        feasible=pcfg["feasible_scale"] if pcfg["feasible"] else None,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--modes", default="inline,lagged,thread")
    ap.add_argument("--plants", default="kin,mujoco")
    ap.add_argument("--episodes", type=int, default=0, help="first N episodes (0: all)")
    ap.add_argument(
        "--thread-episodes",
        type=int,
        default=0,
        help="thread mode: N episodes, those where inline switched classes first (without "
        "inline: the run's MuJoCo test) (0: all)",
    )
    ap.add_argument("--lag", type=int, default=1, help="lagged: control steps behind")
    ap.add_argument(
        "--follow",
        default="mean",
        choices=["mean", "reference"],
        help="the arm follows the plan's mean (the moving test) or the policy's reference (kin)",
    )
    ap.add_argument(
        "--limits",
        default="off",
        help="off, joint (joint by joint, the default's), together (synchronised), on "
        "(limits=True: joint) or a list, e.g. off,joint (with --follow reference)",
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = {}
    for run in args.runs:
        dyn, pcfg = _run_setting(run)
        timing = check_timing(dyn.get("dt", 0.02), dyn.get("duration", 3.0), dyn.get("hold", 1.0))
        envs, own = _envs(run, timing.total)
        pol = protorch.load(run)
        amax = dyn.get("max_acceleration") or pol.task.robot.max_acceleration
        kp = float(dyn.get("kp", 10.0))
        n = envs.shape[0] if args.episodes <= 0 else min(args.episodes, envs.shape[0])
        res: dict = {}
        switched: dict = {}  # plant -> (n,) whether the inline episode switched classes
        unlimited: dict = {}  # (plant, mode) -> (m, 5) the reference's peaks without limits
        for plant in args.plants.split(","):
            phys = None if plant == "kin" else _physics(pol.task, pcfg, dyn, amax)
            for mode, lim in [
                (a, b) for a in args.modes.split(",") for b in args.limits.split(",")
            ]:
                pick = list(range(n))
                if mode == "thread" and args.thread_episodes > 0:  # those that switch first
                    sw = switched.get(plant, own["switched"][:n])
                    pick = sorted(sorted(pick, key=lambda i: not sw[i])[: args.thread_episodes])
                m = len(pick)
                t0 = time.perf_counter()
                r = run_policy_episodes(
                    pol,
                    envs[pick],
                    timing,
                    mode,
                    lag=args.lag,
                    kp=kp,
                    max_acceleration=amax,
                    physics=phys,
                    follow=args.follow,
                    limits={"off": False, "on": True, "joint": "joint", "together": "together"}[
                        lim
                    ],
                )
                if mode == "inline":
                    switched[plant] = r["switches"] > 0
                age = r["age"][:, : timing.moving]
                lost = own[plant][pick] & ~r["success"]  # (m,) the run's own won, this lost
                row = {
                    "episodes": m,
                    "success_rate": float(r["success"].mean()),
                    "run_success_rate": float(own[plant][pick].mean()),
                    "switches": int(r["switches"].sum()),
                    "age_median_ms": float(np.median(age) * 1e3),
                    "age_max_ms": float(age.max() * 1e3),
                    "seconds": round(time.perf_counter() - t0, 1),
                    "failures": {k: int(v.sum()) for k, v in r["failures"].items()},
                    # paired with the run's own on the same episodes
                    "lost": int(lost.sum()),
                    "gained": int((~own[plant][pick] & r["success"]).sum()),
                }
                if args.follow == "reference":  # the reference's largest ratios to the limits
                    peaks = r["peaks"]  # (m, 5)
                    row["peaks"] = [float(x) for x in peaks.max(axis=0)]
                    row["episodes_over_limits"] = int((peaks > 1 + 1e-9).any(axis=1).sum())
                    if lim == "off":
                        unlimited[(plant, mode)] = peaks
                    elif (plant, mode) in unlimited:  # why the limits lose: what was asked
                        asked = unlimited[(plant, mode)][lost]  # (lost, 5)
                        row["lost_unlimited_peaks"] = [
                            [round(float(x), 2) for x in a] for a in asked
                        ]
                key = f"{plant}/{mode}" + (
                    f"/reference/limits={lim}" if args.follow != "mean" else ""
                )
                res[key] = row
                print(f"{run} {key} {json.dumps(row)}", flush=True)
        out[str(run)] = res
        pol.close()
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
