"""PRO side by side with the optimisers users would pick instead, in one run and one table
(run on demand: ``python benchmarks/peers.py --out benchmarks/results/peers.md``).

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
  experiment's demonstrations and priors) fails ``ArmReachTask.success``.
(Problem builders: benchmarks/peers_tasks.py.)

Weights that do not matter, by construction: every problem gets a third DoF (10 more weights)
that no objective reads, like the height of a pen over the table or a wrist angle the task
leaves free; its mean is 0 and its initial std the median initial std of the task's own weights.
The benchmark checks that changing those weights leaves every cost unchanged. "std kept"
(``irrelevant_std_kept`` in peers.json) is the median over those 10 weights of final std /
initial std (1 = kept, PRO's claim; 0 = collapsed), then the median over the problems.

Optimisers: PRO with the relevance noise floor (z = 3, the window experiment's) and, on request,
as written (``noise_floor=None``); EPRO (protorch.optim.EPRO, its defaults: 20 samples per
iteration); RWPO (window only: its sigmoid relevance assumes the Fig. 4 layout) with a relevance learning the budget affords (10 iterations x 20
theta samples x 10 trajectories per objective: 6,000 rollouts, once) and with the authors'
50 x 200 x 50 (1.5 M rollouts, 30 times the default budget: it cannot finish); RWR; CEM
(elite 10 %); CMA-ES (pycma behind the same ask / tell contract, ``CMA_stds`` = the initial stds,
pycma's default population for the dimension). PRO, RWPO and RWR use beta = 20 (the paper's)
on window and point particle, 200 (the paper's) on the beam and the arm; EPRO sets its own;
RWR, CEM and CMA-ES rank or weight the sum of the objectives. Every optimiser runs until it
stops by the experiments' rule (every objective's mean sample cost within 1e-3 over 5
iterations; CMA-ES also by pycma's own ``stop()``) or its next ask would exceed the budget; after
every ``tell`` the current mean is checked against the task's success criterion (a check of the
mean, not counted as a rollout). Each optimiser asks ``S = 100`` samples per update except
CMA-ES, which uses pycma's default population ``4 + 3 ln N`` (14 for N = 30).

Columns: rollouts until the mean first meets the success criterion (median over the repeats that
reached it, and how many did) and the wall time until then, rollouts used until the optimiser
stopped (median), success of the final mean, the final mean's total cost (sum of the
objectives, median), std kept in the weights that do not matter (median), wall time per
iteration (median; ask + rollouts + tell) and rollouts per iteration. Success of the window
task also asks the path to cross the wall inside the window (``WindowTask.success``), which no
objective encodes: a final mean can have a near-zero cost and still fail. ``--out X.md`` also
writes ``X.json``: per task and optimiser ``problems``, ``solved`` (the mean met the criterion
within the budget), ``median_rollouts_to_success`` (over the solved ones, or null) and
``irrelevant_std_kept``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    # one thread everywhere, before numpy and torch load: pycma's numpy (OpenBLAS) and torch's
    # thread pools otherwise fight over the cores and small iterations get 10-30x slower
    os.environ.setdefault(_var, "1")

import argparse
import json
import math
import shlex
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # peers_tasks beside this file

from peers_tasks import (  # noqa: E402
    F64, NUISANCE, Problem, arm_problems, beam_problems, point_particle_problems, window_problems,
)

from protorch import PRO, RWPO, RWR  # noqa: E402
from protorch.data.files import atomic_write_bytes  # noqa: E402
from protorch.optim import CEM, CMAES, EPRO  # noqa: E402

BETA = 20.0  # the paper's point-particle temperature, for PRO, RWPO and RWR on window and particle
BETAS = {"window": BETA, "point_particle": BETA, "beam_position": 200.0, "beam_orientation": 200.0, "arm": 200.0}
EFFICIENT_PRO = "EPRO"
TASKS = {
    "window": window_problems,
    "point_particle": point_particle_problems,
    "beam_position": lambda r: beam_problems(r, "position"),
    "beam_orientation": lambda r: beam_problems(r, "orientation"),
    "arm": arm_problems,
}
DEFAULT_REPEATS = {"window": 5, "point_particle": 20, "beam_position": 5, "beam_orientation": 5, "arm": 20}


def check_nuisance(p: Problem) -> None:
    """The weights that do not matter: changing them by 10 stds changes no cost at all."""
    g = torch.Generator().manual_seed(0)
    w = p.mean + p.var.sqrt() * torch.randn(64, p.mean.shape[0], generator=g, dtype=F64)  # (64, N)
    w2 = w.clone()
    w2[:, p.n_task:] += 10 * p.var[p.n_task:].sqrt() * torch.randn(64, NUISANCE, generator=g, dtype=F64)
    if not torch.equal(p.costs(w), p.costs(w2)):
        raise AssertionError("the nuisance weights change a cost: they are not irrelevant")


def make_optimizer(name: str, p: Problem, seed: int):
    common = dict(num_samples=100, max_iter=10**9, tol=1e-3, window=5, seed=seed)
    beta = BETAS[p.task]
    if name == "PRO":
        return PRO(p.mean, p.var, beta=beta, relevance_samples=200, noise_floor=3.0, **common)
    if name == "PRO (as written)":
        return PRO(p.mean, p.var, beta=beta, relevance_samples=200, noise_floor=None, **common)
    if name == "RWPO":  # a relevance learning the budget affords: 10 x 20 x 10 x 3 objectives = 6,000 rollouts
        return RWPO(p.mean, p.var, beta=beta, num_objectives=3, num_basis=p.num_basis, relevance_iters=10,
                    theta_samples=20, trajectory_samples=10, **common)
    if name == "RWPO (authors')":  # 50 x 200 x 50 x 3 = 1.5 M rollouts for the relevance alone
        return RWPO(p.mean, p.var, beta=beta, num_objectives=3, num_basis=p.num_basis, **common)
    if name == EFFICIENT_PRO:  # its defaults: 20 samples, temperature set for ESS = 5, 10 batches pooled
        return EPRO(p.mean, p.var, **{**common, "num_samples": 20})
    if name == "RWR":
        return RWR(p.mean, p.var, beta=beta, **common)
    if name == "CEM":
        return CEM(p.mean, p.var, elite_frac=0.1, **common)
    if name == "CMA-ES":
        import cma

        popsize = int(cma.CMAOptions().eval("popsize", loc={"N": p.mean.shape[0]}))  # pycma's default, 4 + 3 ln N
        return CMAES(p.mean, p.var, **{**common, "num_samples": popsize})
    raise ValueError(name)


METHODS = ("PRO", EFFICIENT_PRO, "RWR", "RWPO", "CEM", "CMA-ES", "PRO (as written)", "RWPO (authors')")
DEFAULT_METHODS = ("PRO", EFFICIENT_PRO, "RWR", "RWPO", "CEM", "CMA-ES")  # RWPO on the window only (see main)


def run_one(name: str, p: Problem, budget: int) -> dict:
    opt = make_optimizer(name, p, seed=1000 + p.repeat)
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
    std_kept = (var[p.n_task:].sqrt() / p.var[p.n_task:].sqrt()).median().item()
    return {
        "first": first,
        "first_s": first_s,
        "final_success": p.success(mean),
        "final_cost": float(p.costs(mean).sum()),
        "std_kept": std_kept,
        "iter_ms": 1000 * statistics.median(iter_times) if iter_times else float("nan"),
        "iterations": opt.iteration,
        "rollouts": used,
        "seconds": total,
    }


def _std_kept(runs: list[dict]) -> str:
    updated = [r["std_kept"] for r in runs if r["iterations"] > 0]  # an untouched start keeps it trivially
    return f"{statistics.median(updated):.3f}" if updated else "- (no update)"


def _ms(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:.2f}"


def table(results: dict, repeats: int, budget: int, command: str, note: str = "") -> str:
    lines = [
        "# PRO and its peers",
        "",
        f"Command: `{command}`",
        "",
        f"torch {torch.__version__}, {torch.get_num_threads()} thread (torch and numpy), CPU; problems per task: {repeats}; a budget "
        f"of {budget:,} rollouts per run, medians over the repeats. See the docstring of benchmarks/peers.py."
        + (f" {note}" if note else ""),
        "",
        "| task | optimiser | rollouts to success | s to success | rollouts used | final mean succeeds "
        "| final cost | std kept (irrelevant weights) | ms / iteration | rollouts / iteration |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (task, name), runs in results.items():
        reached = [r["first"] for r in runs if r["first"] is not None]
        first = f"{statistics.median(reached):,.0f} ({len(reached)}/{len(runs)})" if reached else f"- (0/{len(runs)})"
        secs = [r["first_s"] for r in runs if r["first_s"] is not None]
        first_s = f"{statistics.median(secs):.3f}" if secs else "-"
        ok = sum(r["final_success"] for r in runs)
        done = [r["rollouts"] / r["iterations"] for r in runs if r["iterations"] > 0]
        per_iter = f"{statistics.median(done):,.0f}" if done else "-"
        lines.append(
            f"| {task} | {name} | {first} | {first_s} | {statistics.median(r['rollouts'] for r in runs):,.0f} "
            f"| {ok}/{len(runs)} "
            f"| {statistics.median(r['final_cost'] for r in runs):.4f} "
            f"| {_std_kept(runs)} "
            f"| {_ms(statistics.median(r['iter_ms'] for r in runs))} | {per_iter} |"
        )
    return "\n".join(lines) + "\n"


def summary(results: dict) -> dict:
    """peers.json: per task and optimiser, problems, solved (the mean met the success criterion
    within the budget), the median rollouts to success over the solved ones and the median
    irrelevant_std_kept (see the module docstring)."""
    tasks: dict = {}
    for (task, name), runs in results.items():
        reached = [r["first"] for r in runs if r["first"] is not None]
        updated = [r["std_kept"] for r in runs if r["iterations"] > 0]
        tasks.setdefault(task, {})[name] = {
            "problems": len(runs),
            "solved": len(reached),
            "median_rollouts_to_success": float(statistics.median(reached)) if reached else None,
            "irrelevant_std_kept": float(statistics.median(updated)) if updated else None,
        }
    return {"efficient_pro": EFFICIENT_PRO, "tasks": tasks}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=None,
                    help=f"problems per task (default {DEFAULT_REPEATS})")
    ap.add_argument("--budget", type=int, default=50_000, help="rollouts per run")
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS), help=f"from {list(METHODS)}")
    ap.add_argument("--note", default="", help="a sentence about the machine, added to the table's header")
    ap.add_argument("--out", default=None, help="also write the table here (atomically), e.g. benchmarks/results/peers.md;"
                    " the JSON summary goes beside it (.json)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    methods = [m for m in args.methods.split(",") if m]
    bad = sorted(set(methods) - set(METHODS))
    if bad:
        ap.error(f"unknown method(s) {bad}; choose from {list(METHODS)}")
    tasks = [t for t in args.tasks.split(",") if t]
    if set(tasks) - set(TASKS):
        ap.error(f"unknown task(s) {sorted(set(tasks) - set(TASKS))}; choose from {list(TASKS)}")
    command = shlex.join(["python", "benchmarks/peers.py", *(sys.argv[1:] if argv is None else argv)])
    results: dict = {}
    for t in tasks:
        problems = TASKS[t](args.repeats or DEFAULT_REPEATS[t])
        for p in problems:
            check_nuisance(p)
        for name in methods:
            if name.startswith("RWPO") and t != "window":
                continue  # its sigmoid relevance basis assumes the 2-DoF layout of the Fig. 4 task
            t0 = time.perf_counter()
            results[(t, name)] = [run_one(name, p, args.budget) for p in problems]
            print(f"{t:>16} {name:<17} {time.perf_counter() - t0:7.1f} s", file=sys.stderr, flush=True)
    repeats = ", ".join(f"{t} {args.repeats or DEFAULT_REPEATS[t]}" for t in tasks)
    text = table(results, repeats, args.budget, command, args.note)
    print(text)
    if args.out:
        out = Path(args.out)
        atomic_write_bytes(out, text.encode())
        body = {"command": command, **summary(results)}
        atomic_write_bytes(out.with_suffix(".json"), (json.dumps(body, indent=1) + "\n").encode())


if __name__ == "__main__":
    main()
