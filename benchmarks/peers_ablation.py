"""EPRO's ingredients one at a time on the point-particle problems of benchmarks/peers.py
(docs/peers.md, section 2; on demand: ``python benchmarks/peers_ablation.py [--problems 20] [--budget 3000]``).

Each variant changes one EPRO default; solved problems, median rollouts to success and the
irrelevant std kept are counted by ``peers.run_one`` exactly as in the benchmark."""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
from pathlib import Path

import torch

from protorch.optim import EPRO

HERE = Path(__file__).resolve().parent
VARIANTS = {
    "defaults": {},
    "linear relevance only (curvature=False)": {"curvature": False},
    "fixed beta = 20": {"beta": 20.0},
    "no pooling (pool=1)": {"pool": 1},
    "no noise floors (noise_floor=None, variance_floor=None)": {"noise_floor": None, "variance_floor": None},
    "one floor for mean and variance (variance_floor=None)": {"variance_floor": None},
    "one floor, z = 3.5 for both (noise_floor=3.5, variance_floor=None)": {"noise_floor": 3.5, "variance_floor": None},
    "raw pool (standardize=False)": {"standardize": False},
}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="point_particle,beam_orientation")
    ap.add_argument("--budget", type=int, default=50_000)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    spec = importlib.util.spec_from_file_location("peers_bench", HERE / "peers.py")
    peers = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = peers
    spec.loader.exec_module(peers)
    print("| task | EPRO variant | solved | median rollouts to success | irrelevant std kept |")
    print("|---|---|---|---|---|")
    for task in args.tasks.split(","):
        problems = peers.TASKS[task](peers.DEFAULT_REPEATS[task])
        for label, option in VARIANTS.items():
            def make(name, p, seed, option=option):
                return EPRO(p.mean, p.var, max_iter=10**9, tol=1e-3, window=5, seed=seed, **option)
            peers.make_optimizer = make
            runs = [peers.run_one(label, p, args.budget) for p in problems]
            reached = [r["first"] for r in runs if r["first"] is not None]
            med = f"{statistics.median(reached):,.0f}" if reached else "-"
            kept = statistics.median(r["std_kept"] for r in runs)
            print(f"| {task} | {label} | {len(reached)} / {len(runs)} | {med} | {kept:.2f} |", flush=True)

if __name__ == "__main__":
    main()
