"""Environment-map timings, both backends side by side (issue 3).

For M known environments and N weights: latency of one-environment predictions (mean only, mean +
exact variance, mean + approximate variance with its max abs error against the exact one), the
cost of adding one environment (alone and followed by the next mean query, which is when the
gpytorch backend redoes its solve) against a full refit. Data like the arm experiment (IV-C):
environments uniform in [0, 1]^4 (obstacle and goal on a table), alpha = 1, variances in
[1e-4, 1e-2]. Run: ``python benchmarks/gp.py [--sizes 30,1000,2024] [--weights 20,70]``.
"""

from __future__ import annotations

import argparse
import statistics

import torch
from _timing import Stopwatch, median_s

from protorch.gp import make_env_map


def _data(m: int, n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    E = torch.rand(m + 1, 4, generator=g, dtype=torch.float64)  # (M+1, 4), last row = query
    MU = torch.randn(m, n, generator=g, dtype=torch.float64)  # (M, N)
    VAR = 10 ** (-4 + 2 * torch.rand(m, n, generator=g, dtype=torch.float64))  # (M, N)
    return E[:m], MU, VAR, E[m:]


def bench(backend: str, m: int, n: int, alpha: float = 1.0) -> dict:
    E, MU, VAR, q = _data(m, n)
    opts = {"capacity": m} if backend == "torch" else {}
    make_env_map(backend, alpha, **opts).fit(E[:8], MU[:8], VAR[:8]).predict(
        q
    )  # first-call overheads
    with Stopwatch() as sw:
        gp = make_env_map(backend, alpha, **opts).fit(E, MU, VAR)
        gp.predict_mean(q)  # gpytorch solves lazily: a refit is ready once it has answered
    refit = sw.wall
    reps = 30 if m <= 1000 else 15
    mean_t = median_s(lambda: gp.predict_mean(q), reps)
    var_reps = 5 if m * n <= 30_000 else 2
    exact_t = median_s(lambda: gp.predict(q), var_reps)
    approx_t = median_s(lambda: gp.predict(q, approx_var=True), reps)
    qs = torch.rand(64, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    err = float((gp.predict(qs, approx_var=True)[1] - gp.predict(qs)[1]).abs().max())
    # add one: fit on M - 3, add the last three one at a time (medians: a single add is noisy)
    gp1 = make_env_map(backend, alpha, **opts).fit(E[:-3], MU[:-3], VAR[:-3])
    gp1.predict_mean(q)
    adds, add_qs = [], []
    for i in range(m - 3, m):
        with Stopwatch() as add:
            gp1.add(E[i : i + 1], MU[i : i + 1], VAR[i : i + 1])
        with Stopwatch() as answer:
            gp1.predict_mean(q)
        adds.append(add.wall)
        add_qs.append(add.wall + answer.wall)
    return dict(
        refit=refit,
        mean=mean_t,
        exact=exact_t,
        approx=approx_t,
        err=err,
        add=statistics.median(adds),
        add_q=statistics.median(add_qs),
    )


def _ms(x: float) -> str:
    return f"{1e3 * x:9.3f}" if x < 10 else f"{x:8.1f}s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="30,1000,2024")
    ap.add_argument("--weights", default="20,70")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    sizes = [int(s) for s in args.sizes.split(",")]
    weights = [int(s) for s in args.weights.split(",")]
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, float64, CPU; times in ms; "
        "ratio = refit / (add + next mean query)"
    )
    cols = ("mean", "mean+var", "mean+~var", "~var err", "add", "add+query", "refit", "ratio")
    print(f"{'M':>5} {'N':>3} {'backend':>8} " + " ".join(f"{c:>10}" for c in cols))
    for m in sizes:
        for n in weights:
            res = {b: bench(b, m, n) for b in ("torch", "gpytorch")}
            for b, r in res.items():
                ratio = r["refit"] / r["add_q"]
                print(
                    f"{m:>5} {n:>3} {b:>8} "
                    + " ".join(
                        f"{v:>10}"
                        for v in (
                            _ms(r["mean"]),
                            _ms(r["exact"]),
                            _ms(r["approx"]),
                            f"{r['err']:.1e}",
                            _ms(r["add"]),
                            _ms(r["add_q"]),
                            _ms(r["refit"]),
                            f"{ratio:.1f}x",
                        )
                    )
                )
            t, g = res["torch"], res["gpytorch"]
            print(
                f"{'':>5} {'':>3} {'g/t':>8} "
                + " ".join(
                    f"{v:>10}"
                    for v in (
                        f"{g['mean'] / t['mean']:.1f}x",
                        f"{g['exact'] / t['exact']:.1f}x",
                        f"{g['approx'] / t['approx']:.1f}x",
                        "",
                        f"{g['add'] / t['add']:.1f}x",
                        f"{g['add_q'] / t['add_q']:.1f}x",
                        f"{g['refit'] / t['refit']:.1f}x",
                        "",
                    )
                )
            )
    print(
        "~var: torch = Nystroem (var_rank 256, var_tol 1e-10, float32 cache), gpytorch = LOVE "
        "(rank 100); "
        "err = max |~var - var| over 64 queries; add = median of 3 single adds at M - 3 .. M - 1. "
        "gpytorch's add only appends and drops its caches."
    )


if __name__ == "__main__":
    main()
