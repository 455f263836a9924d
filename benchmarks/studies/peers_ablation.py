"""EPRO's ingredients one at a time on the problems of benchmarks/studies/peers.py (docs/peers.md,
section 2; on demand: ``python benchmarks/studies/peers_ablation.py [--tasks point_particle] [--seed
0]
[--full-budget]``).

Each variant changes one EPRO default; every count is made by ``peers.run_one`` and
``peers.row_metrics`` exactly as in the benchmark (stopped by the convergence rule, and with
``--full-budget`` also run to the whole budget at ``tol = 0``)."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import torch

from protorch.optim import EPRO

HERE = Path(__file__).resolve().parent
VARIANTS = {
    "defaults": {},
    "no read-weight test (evidence_level=None): the relevance floors alone": {
        "evidence_level": None
    },
    "no trust region (trust_radius=0): a weight not shown to be read stays put": {
        "trust_radius": 0.0
    },
    "a trust region that does not shrink (trust_iterations=10^9)": {"trust_iterations": 10**9},
    "evidence_level=0.1": {"evidence_level": 0.1},
    "evidence_level=0.001": {"evidence_level": 0.001},
    "linear relevance only (curvature=False)": {"curvature": False},
    "fixed beta = 20": {"beta": 20.0},
    "no pooling (pool=1)": {"pool": 1},
    "one floor for the variance, z = 2.5 (variance_floor=None)": {"variance_floor": None},
}


def load_peers():
    spec = importlib.util.spec_from_file_location("peers_bench", HERE / "peers.py")
    peers = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = peers
    spec.loader.exec_module(peers)
    return peers


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="point_particle")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--budget", type=int, default=50_000)
    ap.add_argument(
        "--variants",
        default=None,
        help=f"comma-separated indices into {list(VARIANTS)} (default all)",
    )
    ap.add_argument(
        "--full-budget",
        action="store_true",
        help="also run every variant to the full budget (tol = 0)",
    )
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    peers = load_peers()
    chosen = list(VARIANTS.items())
    if args.variants:
        chosen = [chosen[int(i)] for i in args.variants.split(",")]
    print(
        "| task | EPRO variant | budget | solved | median rollouts to success | final mean "
        "succeeds | std kept p10 "
        "| std kept min | unread mean drift max |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        problems = peers.TASKS[task](args.repeats or peers.DEFAULT_REPEATS[task], args.seed)
        for label, option in chosen:

            def make(name, p, seed, tol=1e-3, option=option):
                return EPRO(p.mean, p.var, max_iter=10**9, tol=tol, window=5, seed=seed, **option)

            peers.make_optimizer = make
            for tol in (1e-3, 0.0) if args.full_budget else (1e-3,):
                m = peers.row_metrics([peers.run_one(label, p, args.budget, tol) for p in problems])
                med = m["median_rollouts_to_success"]
                print(
                    f"| {task} | {label} | {'stopped' if tol else 'full'} | {m['solved']} / "
                    f"{m['problems']} "
                    f"| {'-' if med is None else f'{med:,.0f}'} | {m['final_solved']} / "
                    f"{m['problems']} "
                    f"| {m['std_kept_p10']:.3f} | {m['std_kept_min']:.3f} | "
                    f"{m['mean_drift_max']:.2f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
