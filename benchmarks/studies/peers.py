"""PRO side by side with the optimisers users would pick instead, in one run and one table
(run on demand: ``python benchmarks/studies/peers.py --seed 1 --out
benchmarks/studies/results/peers_seed1.md``).

Problems (each optimiser starts from the same mean and stds and gets the same rollout budget):

- ``window``: the Fig. 4 task, the ProMP of 5 imperfect demonstrations (one demonstration draw
  and optimiser seed per repeat);
- ``point_particle``: 20 single environments of Sec. IV-B (random, fixed seed), started from
  the GP map of the 30 x 3 synthetic demonstrations (Eq. 7, 8): the guess the self-improvement
  loop has to improve (it fails in every environment here);
- ``beam_position``, ``beam_orientation``: the beam's two PRO stages (Sec. IV-A) from the ProMP
  of 10 simulated operator trials (one draw per repeat); success: the four position via points
  within 5 mm, the four via angles within 2 degrees (at the demonstrations' window phases);
- ``arm``: 20 single arm problems (Sec. IV-C), environments whose label-aware GP start (the
  experiment's demonstrations and priors) fails ``ArmReachTask.success``; the optimisers read the
  can objective of ``--arm-objective``: ``volume`` (default: the link capsules near the can, what
  the arm's default success check reads), ``skeleton`` (the arm's line segments, what the success
  check read before the volumes became the default) or ``ee`` (the paper's: the end effector
  alone, whose optimum can leave the success region, docs/peers.md 3d); the success check is the
  experiment's default (the volumes) and the problems are the same under all three.
(Problem builders: benchmarks/studies/peers_tasks.py.)

Weights that do not matter, by construction: every problem gets a third DoF (10 more weights)
that no objective reads, like the height of a pen over the table or a wrist angle the task
leaves free; its mean is 0 and its initial std the median initial std of the task's own weights.
The benchmark checks that changing those weights leaves every cost unchanged.

Seeds: ``--seed S`` shifts every problem seed (demonstration draws, environments) and every
optimiser seed by ``S * SEED_STEP`` (benchmarks/studies/peers_tasks.py). EPRO's floors were tuned on
``S = 0`` and its step settings on ``S = 5..8``; docs/peers.md reports ``S = 1, 2`` and ``5..10``.

Optimisers: PRO with the relevance noise floor (z = 3, the window experiment's) and, on request,
as written (``noise_floor=None``); EPRO (protorch.optim.EPRO, its defaults: 20 samples per
iteration); RWPO (window only: its sigmoid relevance assumes the Fig. 4 layout) with a relevance
learning the budget affords (10 iterations x 20
theta samples x 10 trajectories per objective: 6,000 rollouts, once) and with the authors'
50 x 200 x 50 (1.5 M rollouts, 30 times the default budget: it cannot finish); RWR; CEM
(elite 10 %); CMA-ES (pycma behind the same ask / tell contract, ``CMA_stds`` = the initial stds,
pycma's default population for the dimension). PRO, RWPO and RWR use beta = 20 (the paper's)
on window and point particle, 200 (the paper's) on the beam and the arm; EPRO sets its own;
RWR, CEM and CMA-ES rank or weight the sum of the objectives. Each optimiser asks ``S = 100``
samples per update except EPRO (20) and CMA-ES, which uses pycma's default population
``4 + 3 ln N`` (14 for N = 30).

Every optimiser runs twice per problem with the same seed: until it stops by the experiments'
rule (every objective's mean sample cost within 1e-3 over 5 iterations; CMA-ES also by pycma's own
``stop()``) or its next ask would exceed the budget, and to the full budget (``tol = 0``; pycma's
own ``stop()`` still applies; ``--no-full-budget`` skips it). After every ``tell`` the current
mean is checked against the task's success criterion (a check of the mean, not counted as a
rollout).

Columns: rollouts until the mean *first* meets the success criterion (median over the problems
that reached it, and how many did) and the wall time until then, rollouts used (median), success
of the *final* mean, the final mean's total cost (median), and for the weights that do not matter
the final / initial std per (problem, unread weight): median over problems of the median over the
weights, the 10th percentile and the minimum over all of them, and the largest drift of an
unread weight's mean, ``|final - initial mean| / initial std``; then wall time per iteration
(median; ask + rollouts + tell) and rollouts per iteration. Success of the window task also asks
the path to cross the wall inside the window (``WindowTask.success``), which no objective
encodes. ``--out X.md`` writes the tables and ``X.json`` (or ``--json F``): per task and optimiser
the keys of :func:`row_metrics` (``problems``, ``solved``, ``median_rollouts_to_success``,
``irrelevant_std_kept``, ``final_solved``, ``std_kept_p10``, ``std_kept_min``,
``mean_drift_max``) and ``full_budget``, the same keys at ``tol = 0``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    # one thread everywhere, before numpy and torch load: pycma's numpy (OpenBLAS) and torch's
    # thread pools otherwise fight over the cores and small iterations get 10-30x slower
    os.environ.setdefault(_var, "1")

import argparse
import inspect
import json
import math
import shlex
import statistics
import sys
import time
from pathlib import Path

import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))  # peers_tasks beside this file

from peers_tasks import (  # noqa: E402
    F64,
    NUISANCE,
    Problem,
    arm_problems,
    beam_problems,
    point_particle_problems,
    window_problems,
)

from protorch import PRO, RWPO, RWR  # noqa: E402
from protorch.data.files import atomic_write_bytes  # noqa: E402
from protorch.optim import CEM, CMAES, EPRO  # noqa: E402
from protorch.tasks.arm.collision import CAN_OBJECTIVES  # noqa: E402

BETA = 20.0  # the paper's point-particle temperature, for PRO, RWPO and RWR on window and particle
BETAS = {
    "window": BETA,
    "point_particle": BETA,
    "beam_position": 200.0,
    "beam_orientation": 200.0,
    "arm": 200.0,
}
EFFICIENT_PRO = "EPRO"
TASKS = {  # (repeats, seed set) -> problems
    "window": window_problems,
    "point_particle": point_particle_problems,
    "beam_position": lambda r, seed=0: beam_problems(r, "position", seed),
    "beam_orientation": lambda r, seed=0: beam_problems(r, "orientation", seed),
    "arm": lambda r, seed=0: arm_problems(r, seed, can_objective=ARM_OPTIONS["can_objective"]),
}
ARM_OPTIONS = {"can_objective": "volume"}  # --arm-objective: the can objective the optimisers read
DEFAULT_REPEATS = {
    "window": 5,
    "point_particle": 20,
    "beam_position": 5,
    "beam_orientation": 5,
    "arm": 20,
}


def check_nuisance(p: Problem) -> None:
    """The weights that do not matter: changing them by 10 stds changes no cost at all."""
    g = torch.Generator().manual_seed(0)
    w = p.mean + p.var.sqrt() * torch.randn(64, p.mean.shape[0], generator=g, dtype=F64)  # (64, N)
    w2 = w.clone()
    w2[:, p.n_task :] += (
        10 * p.var[p.n_task :].sqrt() * torch.randn(64, NUISANCE, generator=g, dtype=F64)
    )
    if not torch.equal(p.costs(w), p.costs(w2)):
        raise AssertionError("the nuisance weights change a cost: they are not irrelevant")


# --epro KEY=VALUE: EPRO settings other than its defaults (a sensitivity run)
EPRO_OPTIONS: dict = {}


def make_optimizer(name: str, p: Problem, seed: int, tol: float = 1e-3):
    common = dict(num_samples=100, max_iter=10**9, tol=tol, window=5, seed=seed)
    beta = BETAS[p.task]
    if name == "PRO":
        return PRO(p.mean, p.var, beta=beta, relevance_samples=200, noise_floor=3.0, **common)
    if name == "PRO (as written)":
        return PRO(p.mean, p.var, beta=beta, relevance_samples=200, noise_floor=None, **common)
    if (
        name == "RWPO"
    ):  # a relevance learning the budget affords: 10 x 20 x 10 x 3 objectives = 6,000 rollouts
        return RWPO(
            p.mean,
            p.var,
            beta=beta,
            num_objectives=3,
            num_basis=p.num_basis,
            relevance_iters=10,
            theta_samples=20,
            trajectory_samples=10,
            **common,
        )
    if name == "RWPO (authors')":  # 50 x 200 x 50 x 3 = 1.5 M rollouts for the relevance alone
        return RWPO(p.mean, p.var, beta=beta, num_objectives=3, num_basis=p.num_basis, **common)
    if name == EFFICIENT_PRO:  # its defaults (20 samples, temperature set for its target ESS)
        return EPRO(p.mean, p.var, **{**common, "num_samples": 20, **EPRO_OPTIONS})
    if name == "RWR":
        return RWR(p.mean, p.var, beta=beta, **common)
    if name == "CEM":
        return CEM(p.mean, p.var, elite_frac=0.1, **common)
    if name == "CMA-ES":
        import cma

        popsize = int(
            cma.CMAOptions().eval("popsize", loc={"N": p.mean.shape[0]})
        )  # pycma's default, 4 + 3 ln N
        return CMAES(p.mean, p.var, **{**common, "num_samples": popsize})
    raise ValueError(name)


METHODS = (
    "PRO",
    EFFICIENT_PRO,
    "RWR",
    "RWPO",
    "CEM",
    "CMA-ES",
    "PRO (as written)",
    "RWPO (authors')",
)
DEFAULT_METHODS = (
    "PRO",
    EFFICIENT_PRO,
    "RWR",
    "RWPO",
    "CEM",
    "CMA-ES",
)  # RWPO on the window only (see main)


def run_one(name: str, p: Problem, budget: int, tol: float = 1e-3) -> dict:
    """One optimiser on one problem until it stops (``tol = 0``: until the budget is spent)."""
    opt = make_optimizer(name, p, seed=p.optimizer_seed, tol=tol)
    used, first = 0, (0 if p.success(opt.mean[0]) else None)
    first_s = 0.0 if first == 0 else None
    iter_times, spent, total, it = [], 0.0, 0.0, opt.iteration
    while not opt.stop():
        t0 = time.perf_counter()
        w = opt.ask()  # (S, N)
        if used + w.shape[-2] > budget:
            break
        opt.tell(p.costs(w))
        dt = time.perf_counter() - t0
        spent, total, used = spent + dt, total + dt, used + w.shape[-2]
        if opt.iteration != it:
            iter_times.append(spent)
            spent, it = 0.0, opt.iteration
        if first is None and p.success(opt.mean[0]):
            first, first_s = used, total
    mean, var = opt.mean[0], opt.var[0]
    std0 = p.var[p.n_task :].sqrt()  # (NUISANCE,)
    ratios = (
        var[p.n_task :].sqrt() / std0
    )  # (NUISANCE,): final std / initial std of each unread weight
    drifts = (mean[p.n_task :] - p.mean[p.n_task :]).abs() / std0  # (NUISANCE,): in initial stds
    return {
        "first": first,
        "first_s": first_s,
        "final_success": p.success(mean),
        "final_cost": float(p.costs(mean).sum()),
        "std_kept": ratios.median().item(),
        "std_ratios": ratios.tolist(),
        "drifts": drifts.tolist(),
        "iter_ms": 1000 * statistics.median(iter_times) if iter_times else float("nan"),
        "iterations": opt.iteration,
        "rollouts": used,
        "seconds": total,
        "mean": mean.clone(),  # (N,): the final distribution (not written to peers.json)
        "var": var.clone(),
    }


def row_metrics(runs: list[dict]) -> dict:
    """The peers.json keys of one (task, optimiser) over its problems: ``solved`` (the mean met the
    success criterion at some point within the budget), ``median_rollouts_to_success`` (over the
    solved ones, or None), ``final_solved`` (the final mean succeeds), ``irrelevant_std_kept``
    (median
    over problems of the median over the unread weights of final / initial std), ``std_kept_p10``
    and
    ``std_kept_min`` (10th percentile and minimum of that ratio over every (problem, unread
    weight)),
    ``mean_drift_max`` (largest |final - initial mean| of an unread weight, in its initial stds).
    Problems the optimiser never updated (budget below one iteration) count in none of the std
    keys."""
    reached = [r["first"] for r in runs if r["first"] is not None]
    updated = [r for r in runs if r["iterations"] > 0]
    ratios = torch.tensor([x for r in updated for x in r["std_ratios"]], dtype=F64)
    drifts = [x for r in updated for x in r["drifts"]]
    return {
        "problems": len(runs),
        "solved": len(reached),
        "median_rollouts_to_success": float(statistics.median(reached)) if reached else None,
        "irrelevant_std_kept": float(statistics.median(r["std_kept"] for r in updated))
        if updated
        else None,
        "final_solved": sum(bool(r["final_success"]) for r in runs),
        "std_kept_p10": float(ratios.quantile(0.1)) if updated else None,
        "std_kept_min": float(ratios.min()) if updated else None,
        "mean_drift_max": float(max(drifts)) if updated else None,
    }


def _num(v, fmt: str = ".3f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def _cells(task: str, name: str, runs: list[dict]) -> tuple[str, str]:
    """The table cells of one row up to the rollouts to success, and from the rollouts used to the
    mean drift."""
    m = row_metrics(runs)
    first = (
        f"{m['median_rollouts_to_success']:,.0f} ({m['solved']}/{len(runs)})"
        if m["solved"]
        else f"- (0/{len(runs)})"
    )
    rest = (
        f"{statistics.median(r['rollouts'] for r in runs):,.0f} | {m['final_solved']}/{len(runs)} "
        f"| {statistics.median(r['final_cost'] for r in runs):.4f} | "
        f"{_num(m['irrelevant_std_kept'])} "
        f"| {_num(m['std_kept_p10'])} | {_num(m['std_kept_min'])} | "
        f"{_num(m['mean_drift_max'], '.2f')}"
    )
    return f"| {task} | {name} | {first}", rest


def table(
    results: dict, repeats, budget: int, command: str, note: str = "", full: dict | None = None
) -> str:
    """The markdown table of ``results[(task, optimiser)] = [run_one(...) per problem]`` and, with
    ``full`` (the same runs at ``tol = 0``), a second table at the full budget."""
    lines = [
        "# PRO and its peers",
        "",
        f"Command: `{command}`",
        "",
        f"torch {torch.__version__}, {torch.get_num_threads()} thread (torch and numpy), CPU; "
        f"problems per task: {repeats}; a budget "
        f"of {budget:,} rollouts per run, medians over the repeats. See the docstring of "
        "benchmarks/studies/peers.py." + (f" {note}" if note else ""),
        "",
        "Stopped by the convergence rule (tol = 1e-3):",
        "",
        "| task | optimiser | rollouts to success | s to success | rollouts used | final mean "
        "succeeds | final cost "
        "| std kept (median) | std kept p10 | std kept min | unread mean drift max (stds) | ms / "
        "iteration "
        "| rollouts / iteration |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (task, name), runs in results.items():
        secs = [r["first_s"] for r in runs if r["first_s"] is not None]
        done = [r["rollouts"] / r["iterations"] for r in runs if r["iterations"] > 0]
        first, rest = _cells(task, name, runs)
        lines.append(
            f"{first} | {_num(statistics.median(secs) if secs else None)} | {rest} "
            f"| {_num(statistics.median(r['iter_ms'] for r in runs), '.2f')} "
            f"| {_num(statistics.median(done) if done else None, ',.0f')} |"
        )
    if full:
        lines += [
            "",
            f"Run to the full budget (tol = 0: every optimiser spends the {budget:,} rollouts "
            "unless its own rule stops it, "
            "as pycma's does):",
            "",
            "| task | optimiser | rollouts to success | rollouts used | final mean succeeds | "
            "final cost "
            "| std kept (median) | std kept p10 | std kept min | unread mean drift max (stds) |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        lines += [
            " | ".join(_cells(task, name, runs)) + " |" for (task, name), runs in full.items()
        ]
    return "\n".join(lines) + "\n"


def summary(results: dict, full: dict | None = None) -> dict:
    """peers.json: per task and optimiser the keys of :func:`row_metrics` and, when the full-budget
    runs were made, a ``full_budget`` object with the same keys."""
    tasks: dict = {}
    for key, runs in results.items():
        row = row_metrics(runs)
        if full and key in full:
            row["full_budget"] = row_metrics(full[key])
        tasks.setdefault(key[0], {})[key[1]] = row
    return {"efficient_pro": EFFICIENT_PRO, "tasks": tasks}


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed set: problems and optimiser seeds (0: the published ones)",
    )
    ap.add_argument(
        "--repeats", type=int, default=None, help=f"problems per task (default {DEFAULT_REPEATS})"
    )
    ap.add_argument("--budget", type=int, default=50_000, help="rollouts per run")
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument(
        "--optimizers",
        "--methods",
        dest="methods",
        default=",".join(DEFAULT_METHODS),
        help=f"from {list(METHODS)}",
    )
    ap.add_argument(
        "--no-full-budget",
        dest="full_budget",
        action="store_false",
        help="skip the second run of every optimiser at tol = 0 (to the full budget)",
    )
    ap.add_argument(
        "--note", default="", help="a sentence about the machine, added to the table's header"
    )
    ap.add_argument(
        "--out",
        default=None,
        help="also write the table here (atomically), e.g. benchmarks/studies/results/peers.md;"
        " the JSON summary goes beside it (.json) unless --json names another file",
    )
    ap.add_argument("--json", default=None, help="write the JSON summary here (atomically)")
    ap.add_argument(
        "--arm-objective",
        default="volume",
        choices=CAN_OBJECTIVES,
        help="the arm's can objective: the link capsules' (volume, what the default success check "
        "reads;"
        " the default), the skeleton's or the end effector's (ee, the paper's objective)",
    )
    ap.add_argument(
        "--epro",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an EPRO setting instead of its default (repeatable), e.g. --epro "
        "provisional_step=0.75",
    )
    args = ap.parse_args(argv)
    args.epro_options = {}
    for item in args.epro:
        key, sep, value = item.partition("=")
        if (
            not sep
            or key not in inspect.signature(EPRO.__init__).parameters
            or key in ("mean", "var")
        ):
            ap.error(f"--epro {item!r}: expected KEY=VALUE with KEY an EPRO setting")
        try:
            args.epro_options[key] = yaml.safe_load(value)
        except yaml.YAMLError:
            ap.error(f"--epro {item!r}: {value!r} is not a value")
    args.methods = [m for m in args.methods.split(",") if m]
    bad = sorted(set(args.methods) - set(METHODS))
    if bad:
        ap.error(f"unknown optimiser(s) {bad}; choose from {list(METHODS)}")
    args.tasks = [t for t in args.tasks.split(",") if t]
    if set(args.tasks) - set(TASKS):
        ap.error(
            f"unknown task(s) {sorted(set(args.tasks) - set(TASKS))}; choose from {list(TASKS)}"
        )
    if args.budget < 1:
        ap.error(f"--budget must be >= 1, got {args.budget}")
    return args


def write(args, command: str, results: dict, full: dict) -> str:
    """Print the tables and write them (``--out``) and the JSON (``--json``), atomically; called
    after every (task, optimiser), so a killed run keeps what it finished."""
    repeats = ", ".join(f"{t} {args.repeats or DEFAULT_REPEATS[t]}" for t in args.tasks)
    note = (
        f"Seed set {args.seed}."
        + (f" Arm can objective: {args.arm_objective}." if "arm" in args.tasks else "")
        + (f" {args.note}" if args.note else "")
    )
    text = table(results, repeats, args.budget, command, note, full or None)
    body = (
        json.dumps(
            {
                "command": command,
                "seed": args.seed,
                "budget": args.budget,
                "arm_can_objective": args.arm_objective,
                **summary(results, full or None),
            },
            indent=1,
        )
        + "\n"
    ).encode()
    if args.out:
        atomic_write_bytes(Path(args.out), text.encode())
    if args.json or args.out:
        atomic_write_bytes(
            Path(args.json) if args.json else Path(args.out).with_suffix(".json"), body
        )
    return text


def main(argv=None) -> None:
    args = parse_args(argv)
    EPRO_OPTIONS.clear()
    EPRO_OPTIONS.update(args.epro_options)
    ARM_OPTIONS["can_objective"] = args.arm_objective
    torch.set_num_threads(1)
    command = shlex.join(
        ["python", "benchmarks/studies/peers.py", *(sys.argv[1:] if argv is None else argv)]
    )
    results: dict = {}
    full: dict = {}
    for t in args.tasks:
        problems = TASKS[t](args.repeats or DEFAULT_REPEATS[t], args.seed)
        for p in problems:
            check_nuisance(p)
        for name in args.methods:
            if name.startswith("RWPO") and t != "window":
                continue  # its sigmoid relevance basis assumes the 2-DoF layout of the Fig. 4 task
            for tol, store in (
                ((1e-3, results), (0.0, full)) if args.full_budget else ((1e-3, results),)
            ):
                t0 = time.perf_counter()
                store[(t, name)] = [run_one(name, p, args.budget, tol) for p in problems]
                m = row_metrics(store[(t, name)])
                print(
                    f"{t:>16} {name:<17} tol={tol:g} {time.perf_counter() - t0:7.1f} s  solved "
                    f"{m['solved']} "
                    f"final {m['final_solved']} median {m['median_rollouts_to_success']} p10 "
                    f"{_num(m['std_kept_p10'])} "
                    f"min {_num(m['std_kept_min'])} drift {_num(m['mean_drift_max'], '.2f')}",
                    file=sys.stderr,
                    flush=True,
                )
            write(args, command, results, full)
    print(write(args, command, results, full))


if __name__ == "__main__":
    main()
