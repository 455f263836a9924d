"""The external harness's episodes with and without :func:`tasks.speed_up`, side by side.

    benchmarks/studies/external/.venv/bin/python benchmarks/studies/external/speed.py --tasks
    via_point_reacher,hole_reacher

Per task: (1) a short optimiser run (``--optimizer``, seed 0, context 1, ``--episodes``) on each
env, the two results compared field by field (every curve point, the best sample, the first
success: they must be equal, bit for bit; only the timings differ); (2) ``--batches`` batches of
20 random weight vectors, run alternately on the plain and the sped-up env (the same weights,
the same context), timed with ``time.perf_counter``: milliseconds per episode and the ratio.
Interleaving keeps both under the same load; on a shared machine the ratio is what to read.
``--profile``: instead, where an episode's time goes (``cProfile`` over ``--batches`` x 20
episodes of random weights, plain and sped up): the shares of the calls docs/external.md names.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

TIMINGS = ("seconds", "cpu_seconds")


def same_run(task: str, optimizer: str, episodes: int) -> tuple[bool, dict, dict]:
    """One ``run.run_one`` on the plain env and one on the sped-up env: equal but for
    the timings?"""
    from run import make_optimizer, run_one
    from tasks import Episodes

    out = []
    for fast in (False, True):
        ev = Episodes(task, fast=fast)
        opt = make_optimizer(optimizer, ev.num_weights, 1.0, 20, 0)
        res = run_one(opt, ev, 1, episodes, 100)
        out.append({k: v for k, v in res.items() if k not in TIMINGS})
    return out[0] == out[1], out[0], out[1]


def timing(task: str, batches: int, seed: int = 0) -> tuple[float, float]:
    """Median milliseconds per episode (plain, sped up) over ``batches`` interleaved
    batches of 20."""
    from tasks import Episodes

    plain, fast = Episodes(task, fast=False), Episodes(task, fast=True)
    rng = np.random.default_rng(seed)
    per = {False: [], True: []}
    for b in range(batches):
        w = rng.standard_normal((20, plain.num_weights))  # (20, N)
        order = (False, True) if b % 2 == 0 else (True, False)
        for f in order:
            ev = fast if f else plain
            t = time.perf_counter()
            ev(w, 1)
            per[f].append((time.perf_counter() - t) / 20 * 1e3)
    return statistics.median(per[False]), statistics.median(per[True])


PROFILED = (
    "get_trajectory",
    "get_wrapper_attr",
    "warn",
    "_check_self_collision",
    "check_wall_collision",
    "render",
)


def profile(task: str, episodes: int, seed: int = 0) -> None:
    """Print the share of an episode's time each of :data:`PROFILED` takes, plain and sped up."""
    import cProfile
    import pstats

    from tasks import make_env, run_episode

    for fast in (False, True):
        env = make_env(task, fast)
        w = np.random.default_rng(seed).standard_normal(
            (episodes + 1, env.action_space.shape[0])
        )  # (E + 1, N)
        run_episode(env, w[0], 1)  # warm-up: imports, first allocations
        prof = cProfile.Profile()
        prof.enable()
        for x in w[1:]:
            run_episode(env, x, 1)
        prof.disable()
        stats = pstats.Stats(prof)
        share: dict[str, float] = {}
        for (_, _, fn), (_, _, _, cum, _) in stats.stats.items():
            if fn in PROFILED:
                share[fn] = max(
                    share.get(fn, 0.0), cum / stats.total_tt
                )  # the outermost call of a recursion
        parts = ", ".join(f"{fn} {100 * share.get(fn, 0.0):.1f} %" for fn in PROFILED)
        print(
            f"{task} ({'sped up' if fast else 'plain'}), shares of the profiled time: {parts}",
            flush=True,
        )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", default="via_point_reacher,hole_reacher")
    ap.add_argument("--optimizer", default="EPRO")
    ap.add_argument(
        "--episodes", type=int, default=400, help="budget of the compared optimiser runs"
    )
    ap.add_argument("--batches", type=int, default=10, help="timed batches of 20 episodes per env")
    ap.add_argument(
        "--profile", action="store_true", help="where an episode's time goes, instead of the table"
    )
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    if args.profile:
        for task in args.tasks.split(","):
            profile(task, 20 * args.batches)
        return
    print(
        "| task | optimiser run (seed 0, context 1) | plain env, ms / episode | sped up, ms / "
        "episode | ratio |"
    )
    print("|---|---|---|---|---|")
    for task in args.tasks.split(","):
        equal, a, _ = same_run(task, args.optimizer, args.episodes)
        slow, fast = timing(task, args.batches)
        verdict = "identical" if equal else "DIFFERENT"
        print(
            f"| {task} | {args.optimizer}, {a['episodes']} episodes, final return "
            f"{a['final_return']!r}: {verdict} | "
            f"{slow:.1f} | {fast:.1f} | {slow / fast:.2f} |",
            flush=True,
        )
        if not equal:
            raise SystemExit(f"{task}: the sped-up env changed a result")


if __name__ == "__main__":
    main()
