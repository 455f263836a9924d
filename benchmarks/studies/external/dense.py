"""Why EPRO trails CMA-ES where every weight matters a little: a synthetic stand-in for fancy_gym's
ProMP tasks, seconds instead of hours (runs in protorch's own venv; no fancy_gym):

    python benchmarks/studies/external/dense.py --optimizers
    EPRO,EPRO:nogate,EPRO:nogate_nofloor,CMAES,CMAES:diag

A quadratic over ``N = 35`` weights (box pushing's count) that reads every one of them,
``c(w) = |A (w - w*)|^2 / N``, ``A = Q diag(s)``, ``Q`` a random rotation, ``s`` log-spaced from 1
to
``--cond`` (``cond = 1``: a sphere, where correlated search buys nothing), ``w* ~ N(0, 2^2 I)``,
the start ``N(0, I)`` as in benchmarks/studies/external/run.py (``--start-std``: others), 20 samples
an iteration, ``--episodes``
evaluations, ``tol = 0``. Per (problem, optimiser): the final mean's cost, the median std of
the search distribution, and for EPRO how many weights its gate declared read, at a few budgets.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from run import diagnostics, ints, make_optimizer


def problem(seed: int, n: int, cond: float):
    """``c(w (..., N)) -> (...)`` and ``w*``."""
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=g, dtype=torch.float64))
    a = q * torch.logspace(0, math.log10(cond), n, dtype=torch.float64)  # (N, N)
    w_star = 2.0 * torch.randn(n, generator=g, dtype=torch.float64)  # (N,)
    return (lambda w: ((w - w_star) @ a).pow(2).sum(-1) / n), w_star


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--optimizers", default="EPRO,EPRO:nogate,EPRO:nofloor,EPRO:nogate_nofloor,CMAES,CMAES:diag"
    )
    ap.add_argument("--cond", default="1,10", help="comma-separated condition numbers of A")
    ap.add_argument("--problems", default="0,1", help="problem (and optimiser) seeds")
    ap.add_argument("--episodes", type=int, default=1600)
    ap.add_argument("--report", default="400,800,1600", help="budgets reported")
    ap.add_argument("--weights", type=int, default=35)
    ap.add_argument(
        "--start-std", default="1", help="comma-separated start stds (the start N(0, std^2 I))"
    )
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    report = ints(args.report)
    stds = [float(v) for v in args.start_std.split(",")]
    print(
        "| cond | problem | start std | optimiser | "
        + " | ".join(f"cost at {b}" for b in report)
        + " | median std at the end | read weights at the end |"
    )
    print("|---|---|---|---|" + "---|" * len(report) + "---|---|")
    for cond in [float(c) for c in args.cond.split(",")]:
        for seed in ints(args.problems):
            f, _ = problem(seed, args.weights, cond)
            for std, name in [(s, n) for s in stds for n in args.optimizers.split(",")]:
                opt = make_optimizer(name, args.weights, std, 20, seed)
                used, costs = 0, {}
                while used + 20 <= args.episodes:
                    w = opt.ask()  # (S, N)
                    opt.tell(f(w)[:, None])
                    used += 20
                    if used in report:
                        costs[used] = float(f(opt.mean[0]))
                d = diagnostics(opt)
                cells = " | ".join(f"{costs[b]:.4f}" if b in costs else "-" for b in report)
                print(
                    f"| {cond:g} | {seed} | {std:g} | {name} | {cells} | {d['std_median']:.3f} | "
                    f"{d.get('read', '-')} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
