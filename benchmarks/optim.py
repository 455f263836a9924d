"""Optimiser speed, side by side in one run (run on demand: ``python benchmarks/optim.py``).

1. The relevance: PRO's Pearson correlation against RWPO's iterative learning on the Fig. 4
   window task (5 demonstrations, 2 DoF x 10 weights, 3 objectives), rollouts included, as the
   paper timed them (0.02 s vs 84.47 s).
2. Batching: PRO iterations per second on the window task for B = 1 and B = 256 independent
   problems advanced by one ask/tell per round, and the per-problem speed-up.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from protorch import PRO, RWPO, ProMP
from protorch.tasks import WindowTask


def window_problem(seed: int = 0, dtype=torch.float64, device="cpu"):
    task = WindowTask()
    demos = task.demonstrations(5, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    promp = ProMP(2, 10, 100, dtype=dtype, device=device).fit([d.to(device) for d in demos])
    return task, promp, (lambda w: task.costs(promp.trajectory(w)))


def bench_relevance(repeats: int, device: str) -> tuple[float, float]:
    task, promp, f = window_problem(device=device)
    pro_t, rwpo_t = [], []
    for r in range(repeats):
        pro = PRO(promp.mean, promp.var, beta=20.0, relevance_samples=200, noise_floor=3.0, max_iter=5, seed=r)
        pro.minimize(f)
        pro_t += pro.relevance_seconds[1:]  # the first includes one-off warm-up
        rwpo = RWPO(promp.mean, promp.var, beta=20.0, num_objectives=3, num_basis=10, max_iter=1, seed=r)
        rwpo.minimize(f)
        rwpo_t += rwpo.relevance_seconds
    return statistics.median(pro_t), statistics.median(rwpo_t)


def bench_batch(batch: int, iters: int, device: str) -> float:
    """Seconds per PRO iteration for ``batch`` problems at once."""
    task, promp, f = window_problem(device=device)
    mean = promp.mean.expand(batch, -1).clone()
    var = promp.var.expand(batch, -1).clone()
    opt = PRO(mean, var, beta=20.0, num_samples=100, max_iter=iters + 2, tol=0.0, seed=0)
    for _ in range(2):  # warm-up iterations
        it = opt.iteration
        while opt.iteration == it:
            opt.tell(f(opt.ask()))
    t0 = time.perf_counter()
    while not opt.stop():
        opt.tell(f(opt.ask()))
    if device == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - t0) / iters


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, device {args.device}\n")
    pro_s, rwpo_s = bench_relevance(args.repeats, args.device)
    print("| relevance (window task, rollouts included) | seconds |")
    print("|---|---|")
    print(f"| PRO (Pearson, 200 samples) | {pro_s:.5f} |")
    print(f"| RWPO (50 x 200 x 50 learning) | {rwpo_s:.3f} |")
    print(f"| ratio RWPO / PRO | {rwpo_s / pro_s:,.0f}x |  (paper: 84.47 s / 0.02 s = 4,224x)\n")
    one = bench_batch(1, args.iters, args.device)
    many = bench_batch(256, max(args.iters // 3, 5), args.device)
    print("| PRO batch | s / iteration | problem-iterations / s | per-problem speed-up |")
    print("|---|---|---|---|")
    print(f"| B = 1 | {one:.4f} | {1 / one:,.0f} | 1.0x |")
    print(f"| B = 256 | {many:.4f} | {256 / many:,.0f} | {256 * one / many:,.1f}x |")


if __name__ == "__main__":
    main()
