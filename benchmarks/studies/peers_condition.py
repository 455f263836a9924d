"""What the kept variance buys: conditioning each optimiser's final distribution on a changed
environment, without further optimisation (docs/peers.md, section 5; on demand:
``python benchmarks/studies/peers_condition.py [--seed S] [--tasks point_particle,arm] [--json
F]``).

The problems, optimisers, budgets and seeds are those of benchmarks/studies/peers.py (stopped by the
convergence rule). Each optimiser's final ``N(mean, diag(var))`` over the task's weights becomes a
ProMP (the nuisance DoF is left out: with a diagonal covariance, conditioning the task's DoFs does
not touch it), which ``ProMP.condition`` adapts to a change of the environment; the conditioned
mean is judged by the task's own success check in the changed environment:

- point particle, ``goal``: the goal moved by 1 unit in a random direction (clipped to the
  authors' goal range), the ProMP conditioned at phase 1 on the new goal;
- point particle, ``hole``: the hole moved 1.5 units up or down (within 1..9), the ProMP
  conditioned on the new hole centre at the phase where its mean crosses the wall;
- arm, ``goal``: the goal moved 5 cm in a random direction on the table; the final joint
  configuration moved by damped least squares from the mean's to reach it (the hand's height
  kept), and the ProMP conditioned at phase 1 on that configuration.

Two observation models: ``exact`` (``y_cov = 0``: the via point is met exactly and the
distribution decides only how the rest of the path deforms) and ``soft`` (``y_cov = tol^2``, tol
0.05 units for the particle, 0.01 rad per joint for the arm: a distribution whose std there is
far below tol barely moves). Rows "not conditioned" (the optimised mean as it is) and "start"
(the start distribution, the GP map's guess, conditioned before any optimisation) frame them.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import shlex
import sys
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from peers_tasks import F64, Problem  # noqa: E402

from protorch.data.files import atomic_write_bytes  # noqa: E402
from protorch.tasks.arm.collision import CAN_OBJECTIVES  # noqa: E402

SHIFTS = {"point_particle": ("goal", "hole"), "arm": ("goal",)}
TOL = {"point_particle": 0.05, "arm": 0.01}  # soft conditioning: the via point's std (units / rad)
DRAWS = 3  # random goal shifts per problem (the hole moves once up and once down)


def load_peers():
    spec = importlib.util.spec_from_file_location("peers_bench", HERE / "peers.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def particle_changes(
    p: Problem, mean_traj: torch.Tensor, g: torch.Generator
) -> list[tuple[str, torch.Tensor, float, torch.Tensor]]:
    """``(kind, new env (6,), phase, via point (2,))`` for the point particle: the goal moved 1 unit
    (``DRAWS`` directions), the hole moved 1.5 up and 1.5 down."""
    env, out = p.env, []
    for _ in range(DRAWS):
        a = 2 * math.pi * float(torch.rand((), generator=g, dtype=F64))
        goal = env[4:6] + torch.tensor([math.cos(a), math.sin(a)], dtype=F64)
        goal = torch.stack([goal[0].clamp(env[2] + 1.5, 10.0), goal[1].clamp(0.0, 10.0)])
        new = env.clone()
        new[4:6] = goal
        out.append(("goal", new, 1.0, goal))
    x = mean_traj[:, 0]  # (T,)
    crossing = int((x - env[2]).abs().argmin())
    phase = crossing / (mean_traj.shape[0] - 1)
    for dy in (1.5, -1.5):
        new = env.clone()
        new[3] = (env[3] + dy).clamp(1.0, 9.0)
        out.append(("hole", new, phase, new[2:4].clone()))
    return out


def arm_goal_configuration(
    task, q: torch.Tensor, goal: torch.Tensor, iters: int = 30, damping: float = 1e-4
) -> torch.Tensor:
    """Damped least squares from ``q (7,)`` until the end effector reaches ``goal (3,)``."""
    q = q.clone()
    for _ in range(iters):
        ee = lambda x: task.kinematics.link_positions(x[None])[0, -1]  # noqa: E731  (7,) -> (3,)
        err = goal - ee(q)  # (3,)
        if float(err.norm()) < 1e-6:
            break
        jac = torch.autograd.functional.jacobian(ee, q)  # (3, 7)
        q = q + jac.T @ torch.linalg.solve(jac @ jac.T + damping * torch.eye(3, dtype=q.dtype), err)
    return q


def arm_changes(
    p: Problem, mean_traj: torch.Tensor, g: torch.Generator
) -> list[tuple[str, torch.Tensor, float, torch.Tensor]]:
    """``(kind, new env (4,), phase 1, goal configuration (7,))``: the goal moved 5 cm (``DRAWS``
    directions, kept on the table)."""
    task, env, out = p.task_obj, p.env, []
    (x0, x1), (y0, y1) = task.table
    for _ in range(DRAWS):
        a = 2 * math.pi * float(torch.rand((), generator=g, dtype=F64))
        new = env.clone()
        new[2] = (env[2] + 0.05 * math.cos(a)).clamp(x0, x1)
        new[3] = (env[3] + 0.05 * math.sin(a)).clamp(y0, y1)
        out.append(
            ("goal", new, 1.0, arm_goal_configuration(task, mean_traj[-1], task.goal_point(new)))
        )
    return out


def adapted(
    p: Problem, mean: torch.Tensor, var: torch.Tensor, changes, soft: bool
) -> list[bool | None]:
    """Success of the conditioned mean in each changed environment (None: conditioning failed,
    e.g. a zero variance at the via point with ``y_cov = 0``)."""
    n = p.n_task
    model = p.promp.set_distribution(mean[:n].clone(), var=var[:n].clamp_min(0).clone())
    tol = TOL[p.task] if soft else 0.0
    out = []
    for _, env, phase, y in changes:
        try:
            cond = model.condition(phase, y, y_cov=tol**2)
        except ValueError:
            out.append(None)
            continue
        out.append(bool(p.task_obj.success(cond.mean_trajectory(), env)))
    return out


def evaluate(p: Problem, mean: torch.Tensor, var: torch.Tensor, seed: int) -> dict:
    """Per kind of change: successes not conditioned, conditioned exactly, conditioned softly, and
    the same counts over the cases whose original problem the mean solves (``*_of_solved``)."""
    g = torch.Generator().manual_seed(seed)
    n = p.n_task
    mean_traj = p.promp.trajectory(mean[:n])  # (T, D)
    changes = (particle_changes if p.task == "point_particle" else arm_changes)(p, mean_traj, g)
    plain = [bool(p.task_obj.success(mean_traj, env)) for _, env, _, _ in changes]
    exact, soft = adapted(p, mean, var, changes, False), adapted(p, mean, var, changes, True)
    solved = bool(p.task_obj.success(mean_traj, p.env))
    out: dict = {}
    for i, (kind, *_rest) in enumerate(changes):
        row = out.setdefault(
            kind,
            dict.fromkeys(
                (
                    "cases",
                    "not_conditioned",
                    "exact",
                    "soft",
                    "failed",
                    "cases_of_solved",
                    "exact_of_solved",
                    "soft_of_solved",
                ),
                0,
            ),
        )
        row["cases"] += 1
        row["not_conditioned"] += plain[i]
        row["exact"] += bool(exact[i])
        row["soft"] += bool(soft[i])
        row["failed"] += (exact[i] is None) + (soft[i] is None)
        row["cases_of_solved"] += solved
        row["exact_of_solved"] += solved and bool(exact[i])
        row["soft_of_solved"] += solved and bool(soft[i])
    return out


def merge(rows: list[dict]) -> dict:
    total: dict = {}
    for r in rows:
        for kind, counts in r.items():
            t = total.setdefault(kind, dict.fromkeys(counts, 0))
            for k, v in counts.items():
                t[k] += v
    return total


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--budget", type=int, default=50_000)
    ap.add_argument("--tasks", default="point_particle,arm")
    ap.add_argument("--optimizers", default="PRO,EPRO,RWR,CEM,CMA-ES")
    ap.add_argument(
        "--arm-objective",
        default="skeleton",
        choices=CAN_OBJECTIVES,
        help="the arm's can objective the optimisers read (benchmarks/studies/peers.py "
        "--arm-objective)",
    )
    ap.add_argument("--json", default=None, help="write the counts here (atomically)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    peers = load_peers()
    peers.ARM_OPTIONS["can_objective"] = args.arm_objective
    command = shlex.join(
        [
            "python",
            "benchmarks/studies/peers_condition.py",
            *(sys.argv[1:] if argv is None else argv),
        ]
    )
    results: dict = {}
    print(
        "| task | change | distribution | cases | not conditioned | conditioned, exact | "
        "conditioned, soft "
        "| cases whose problem the mean solves | ... conditioned, exact | ... conditioned, soft |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for task in [t for t in args.tasks.split(",") if t]:
        if task not in SHIFTS:
            ap.error(f"--tasks: conditioning is measured on {sorted(SHIFTS)}, got {task!r}")
        problems = peers.TASKS[task](args.repeats, args.seed)
        for name in ["start", *[m for m in args.optimizers.split(",") if m]]:
            t0 = time.perf_counter()
            rows = []
            for p in problems:
                if name == "start":
                    mean, var = p.mean, p.var
                else:
                    r = peers.run_one(name, p, args.budget)
                    mean, var = r["mean"], r["var"]
                rows.append(evaluate(p, mean, var, seed=7 + p.repeat + 100_003 * args.seed))
            total = merge(rows)
            results.setdefault(task, {})[name] = total
            for kind, c in total.items():
                print(
                    f"| {task} | {kind} | {name} | {c['cases']} | {c['not_conditioned']} | "
                    f"{c['exact']} | {c['soft']} "
                    f"| {c['cases_of_solved']} | {c['exact_of_solved']} | {c['soft_of_solved']} |",
                    flush=True,
                )
            print(f"{task} {name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    if args.json:
        body = {
            "command": command,
            "seed": args.seed,
            "arm_can_objective": args.arm_objective,
            "tasks": results,
        }
        atomic_write_bytes(Path(args.json), (json.dumps(body, indent=1) + "\n").encode())


if __name__ == "__main__":
    main()
