"""Why the paper's PRO fails point-particle problems that CMA-ES solves (docs/peers.md, section 1;
on demand: ``python benchmarks/studies/peers_diagnose.py [--problems 20] [--iters 40]``).

PRO with benchmarks/studies/peers.py's settings on its point-particle problems; per problem: the
rollouts until the mean first succeeds, the final mean's three costs, the weights with relevance
> 0 per objective (and among the nuisance weights), the median effective sample size
``(sum R)^2 / sum R^2`` of PRO's per-objective rewards over the first and the last 9 updates, and
the task weights' median std relative to the start."""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from peers_tasks import point_particle_problems  # noqa: E402

from protorch.optim import PRO  # noqa: E402
from protorch.optim.functional import stable_rewards  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", type=int, default=20)
    ap.add_argument("--iters", type=int, default=40)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print(
        "| problem | rollouts to success | final costs (start, clearance, goal) | relevant weights "
        "per objective "
        "| relevant nuisance | ESS first 9 | ESS last 9 | task std kept |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for p in point_particle_problems(args.problems):
        opt = PRO(
            p.mean,
            p.var,
            beta=20.0,
            relevance_samples=200,
            noise_floor=3.0,
            num_samples=100,
            max_iter=args.iters,
            tol=0,
            seed=1000 + p.repeat,
        )
        ess, first, used = [], None, 0
        while not opt.stop():
            w = opt.ask()
            c = p.costs(w)
            o = opt.asked_objective
            if o is not None:
                r = stable_rewards(c[..., o], 20.0)
                ess.append(float(r.sum() ** 2 / r.pow(2).sum()))
            opt.tell(c)
            used += w.shape[0]
            if first is None and p.success(opt.mean[0]):
                first = used
        f, n = opt.relevance[0], p.n_task  # (O, N)
        costs = ", ".join(f"{v:.3f}" for v in p.costs(opt.mean[0]).tolist())
        kept = float(opt.var[0, :n].sqrt().median() / p.var[:n].sqrt().median())
        print(
            f"| {p.repeat} | {first if first is not None else '-'} | {costs} "
            f"| {[int((f[o, :n] > 0).sum()) for o in range(f.shape[0])]} | "
            f"{int((f[:, n:] > 0).sum())} "
            f"| {statistics.median(ess[:9]):.1f} | {statistics.median(ess[-9:]):.1f} | {kept:.3f} "
            "|",
            flush=True,
        )


if __name__ == "__main__":
    main()
