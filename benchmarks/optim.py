"""Optimiser speed, side by side in one run (run on demand: ``python benchmarks/optim.py``).

1. The relevance: PRO's Pearson correlation against RWPO's iterative learning on the Fig. 4
   window task (5 demonstrations, 2 DoF x 10 weights, 3 objectives), rollouts included, as the
   paper timed them (0.02 s vs 84.47 s).
2. Batching: PRO iterations per second on the window task for B = 1 and B = 256 independent
   problems advanced by one ask/tell per round, and the per-problem speed-up, end to end and for
   PRO alone (ask + tell, the objective's time taken out); with the objective as written,
   evaluated 16 problems at a time (cache-sized chunks), and evaluated as the self-improvement
   loop does (:func:`asked_objective`: only the objective PRO's update reads, the start and end
   distances on their two time steps, 16 problems at a time). What bounds each: the torch operations
   one iteration dispatches (B = 1 pays their fixed cost) and the objective's memory traffic
   against the machine's copy bandwidth (B = 256).

``--dtype float32`` runs the batching part in float32 (the loop's ``eval_dtype``); ``--clock cpu``
times it in this process's CPU seconds instead of wall seconds (on a machine other programs
load; with ``OMP_NUM_THREADS=1`` that is one core's work).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from _timing import call_times

from protorch import PRO, RWPO, ProMP
from protorch.loop.phases import Evaluator
from protorch.tasks import WindowTask


def window_problem(seed: int = 0, dtype=torch.float64, device="cpu"):
    task = WindowTask()
    demos = task.demonstrations(5, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    promp = ProMP(2, 10, 100, dtype=dtype, device=device).fit([d.to(device) for d in demos])
    return task, promp, (lambda w: task.costs(promp.trajectory(w)))


def asked_objective(task: WindowTask, promp: ProMP, opt):
    """The window task's costs ``(B, S, N) -> (B, S, 3)`` computed as the loop's evaluation computes
    them (``protorch.loop.phases.sample_costs``): where ``opt``'s pending ask feeds one objective's
    update (``opt.asked_objective``; PRO's relevance ask reads all three) only that column is
    computed (``WindowTask.objective_cost``; the others are 0, which the update never reads), the
    start and end distances on the trajectory's first and last steps alone
    (``Evaluator.sample_trajectory``: the same numbers as the full trajectory's)."""
    ev = Evaluator.build(
        task, promp, eval_dtype=None, sample_steps=None, labeler=None, dtype=promp.basis.dtype
    )

    def f(w):  # (B, S, N) -> (B, S, 3)
        o = opt.asked_objective
        if o is None:
            return task.costs(promp.trajectory(w))
        out = w.new_zeros(*w.shape[:-1], 3)  # (B, S, 3)
        out[..., o] = task.objective_cost(ev.sample_trajectory(w, task.objective_steps(o)), o)
        return out

    return f


def bench_relevance(repeats: int, device: str) -> tuple[float, float]:
    task, promp, f = window_problem(device=device)
    pro_t, rwpo_t = [], []
    for r in range(repeats):
        pro = PRO(
            promp.mean,
            promp.var,
            beta=20.0,
            relevance_samples=200,
            noise_floor=3.0,
            max_iter=5,
            seed=r,
        )
        pro.minimize(f)
        pro_t += pro.relevance_seconds[1:]  # the first includes one-off warm-up
        rwpo = RWPO(
            promp.mean, promp.var, beta=20.0, num_objectives=3, num_basis=10, max_iter=1, seed=r
        )
        rwpo.minimize(f)
        rwpo_t += rwpo.relevance_seconds
    return statistics.median(pro_t), statistics.median(rwpo_t)


def bench_batch(
    batch: int,
    iters: int,
    device: str,
    rows: int | None = None,
    dtype=torch.float64,
    clock=time.perf_counter,
    asked: bool = False,
) -> tuple[float, float]:
    """Seconds per PRO iteration for ``batch`` problems at once, and the part of it spent in the
    objective (``rows``: evaluate it that many problems at a time; ``asked``: only what the update
    reads, :func:`asked_objective`), on ``clock``."""
    task, promp, f = window_problem(dtype=dtype, device=device)
    spent = [0.0]

    def objective(w):  # (B, S, N) -> (B, S, 3), timed
        t = clock()
        out = (
            f(w)
            if rows is None
            else torch.cat([f(w[i : i + rows]) for i in range(0, w.shape[0], rows)])
        )
        spent[0] += clock() - t
        return out

    mean = promp.mean.expand(batch, -1).clone()
    var = promp.var.expand(batch, -1).clone()
    opt = PRO(mean, var, beta=20.0, num_samples=100, max_iter=iters + 2, tol=0.0, seed=0)
    if asked:
        f = asked_objective(task, promp, opt)
    for _ in range(2):  # warm-up iterations
        it = opt.iteration
        while opt.iteration == it:
            opt.tell(objective(opt.ask()))
    spent[0] = 0.0
    t0 = clock()
    while not opt.stop():
        opt.tell(objective(opt.ask()))
    if device == "cuda":
        torch.cuda.synchronize()
    return (clock() - t0) / iters, spent[0] / iters


def ops_per_iteration(device: str) -> int:
    """The torch operations one B = 1 PRO iteration dispatches, objective included."""
    task, promp, f = window_problem(device=device)
    opt = PRO(
        promp.mean[None], promp.var[None], beta=20.0, num_samples=100, max_iter=3, tol=0.0, seed=0
    )
    opt.tell(f(opt.ask()))
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        it = opt.iteration
        while opt.iteration == it:
            opt.tell(f(opt.ask()))
    return sum(
        e.count
        for e in prof.key_averages()
        if not e.key.startswith(("aten::view", "aten::as_strided"))
    )


def copy_bandwidth(device: str) -> float:
    """GB/s of a 256 MB tensor copy (read + write), the memory bound of elementwise work."""
    x = torch.ones(2**26, device=device)
    y = torch.empty_like(x)
    y.copy_(x)
    sync = torch.cuda.synchronize if device == "cuda" else None
    seconds = sum(call_times(lambda: y.copy_(x), 5, warmup=0, sync=sync))
    return 5 * 2 * x.numel() * 4 / seconds / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--dtype", choices=("float64", "float32"), default="float64", help="of the batching part"
    )
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall", help="of the batching part")
    ap.add_argument(
        "--batch-only", action="store_true", help="the batching part alone (no relevance timing)"
    )
    args = ap.parse_args()
    dtype, clock = (
        getattr(torch, args.dtype),
        (time.perf_counter if args.clock == "wall" else time.process_time),
    )
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, device {args.device}; "
        f"batching in {args.dtype}, {args.clock} seconds\n"
    )
    if not args.batch_only:
        pro_s, rwpo_s = bench_relevance(args.repeats, args.device)
        print("| relevance (window task, rollouts included) | seconds |")
        print("|---|---|")
        print(f"| PRO (Pearson, 200 samples) | {pro_s:.5f} |")
        print(f"| RWPO (50 x 200 x 50 learning) | {rwpo_s:.3f} |")
        print(
            f"| ratio RWPO / PRO | {rwpo_s / pro_s:,.0f}x |  (paper: 84.47 s / 0.02 s = 4,224x)\n"
        )
    print(
        "| PRO batch | s / iteration | of it the objective | per-problem speed-up | PRO alone (ask "
        "+ tell): speed-up |"
    )
    print("|---|---|---|---|---|")
    for asked in (False, True):
        one, one_f = bench_batch(1, args.iters, args.device, dtype=dtype, clock=clock, asked=asked)
        what = (
            "the objective only as the update reads it (the loop's evaluation)"
            if asked
            else "the objective as written"
        )
        print(f"| B = 1, {what} | {one:.4f} | {one_f:.4f} | 1.0x | 1.0x |")
        for rows in (16,) if asked else (None, 16):
            many, many_f = bench_batch(
                256, max(args.iters // 3, 5), args.device, rows, dtype, clock, asked
            )
            label = f"{what}, 16 problems at a time" if rows else what
            print(
                f"| B = 256, {label} | {many:.4f} | {many_f:.4f} | {256 * one / many:,.1f}x "
                f"| {256 * (one - one_f) / (many - many_f):,.1f}x |"
            )
    ops = ops_per_iteration(args.device)
    # each ask's trajectories (B, S, T, 2) in the dtype: written by the ProMP, read by the costs
    traj_gb = 256 * (200 + 3 * 100) * 100 * 2 * dtype.itemsize / 1e9
    print(
        f"\nB = 1 dispatches {ops} torch operations per iteration: {1e6 * one / ops:.1f} us each, "
        f"end to end; the copy bandwidth here is {copy_bandwidth(args.device):.1f} GB/s, and B = "
        "256 "
        f"writes {traj_gb:.2f} GB of trajectories per iteration before its costs read them."
    )


if __name__ == "__main__":
    main()
