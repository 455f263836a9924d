"""Environment maps as the data set grows: memory and latency over M, every backend until it runs
out of the machine.

For each map variant and each M: build (fit) time, the peak resident memory (RSS) of a process
that only builds and queries that map, the time of adding one environment (median, 99th
percentile and worst over ``--adds`` adds after the fit), the latency of one query: mean only,
and mean + variance (medians; the exact variance), and mean + variance of ``--queries`` queries in
one call (the loop's way), per query. The torch backend gets the
capacity for the adds up front (growing its ``(N, cap, cap)`` factors by 1.5x would otherwise
dominate the add and the peak). Data like the arm experiment (IV-C): 4-D
environments uniform on a 0.6 m square table (obstacle and goal), N = 70 weights varying smoothly
with the environment, variances in [1e-4, 1e-2], alpha = 30, one label.

Every (variant, M) runs in its own subprocess under an address-space limit (``--limit-gb``,
default 8), so a map that needs more is recorded as "out of memory" instead of taking the shared
machine down; a variant that ran out (or took longer than ``--timeout`` s) is not tried at larger M.

    python benchmarks/gp_scaling.py [--sizes 1000,2000,5000,20000,100000] [--threads 1]
        [--variants torch,gpytorch,torch:nearest_k=30,sparse,sparse:nearest_k=30] [--limit-gb 8]
    python benchmarks/gp_scaling.py --search   # the neighbour search alone, both index kinds
    python benchmarks/gp_scaling.py --growth --variants sparse   # every add from 1,000 to 100,000

``--growth`` fits the first size and then adds one environment at a time up to the last, timing
every add: median, 99th percentile and worst per range of M (the adds that allocate a storage
block or build a k-d tree are among them), the peak RSS, and the median mean + variance query on
the grown map at the end.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys

import torch
from _timing import Stopwatch, per_item, percentile

from protorch.gp import make_env_map
from protorch.gp.neighbours import INDEX_KINDS, NeighbourIndex

ALPHA, ENV_DIM, WEIGHTS, TABLE = 30.0, 4, 70, 0.6
VARIANTS = "torch,gpytorch,torch:nearest_k=30,sparse,sparse:index=brute,sparse:nearest_k=30"


def smooth_data(m: int, n: int, *, d: int = ENV_DIM, seed: int = 0, side: float = TABLE):
    """``m`` environments uniform in ``[0, side]^d`` and ``n`` weights, each a random smooth
    function of the environment (sines of about the kernel's length scale), with variances in
    [1e-4, 1e-2]: ``E (m, d), MU (m, n), VAR (m, n)``."""
    g = torch.Generator().manual_seed(seed)
    E = side * torch.rand(m, d, generator=g, dtype=torch.float64)  # (M, d)
    freq = 4.0 * torch.randn(8, d, generator=g, dtype=torch.float64)  # (8, d) ~ 1 / (25 cm)
    phase = 6.3 * torch.rand(8, generator=g, dtype=torch.float64)  # (8,)
    amp = torch.randn(8, n, generator=g, dtype=torch.float64) / 8**0.5  # (8, N)
    MU = torch.sin(E @ freq.T + phase) @ amp  # (M, N)
    VAR = 10 ** (-4 + 2 * torch.rand(m, n, generator=g, dtype=torch.float64))  # (M, N)
    return E, MU, VAR


def parse_variant(text: str) -> tuple[str, dict]:
    """``"sparse:nearest_k=30;index=brute"`` -> ``("sparse", {"nearest_k": 30, "index":
    "brute"})``."""
    backend, _, rest = text.partition(":")
    opts = {}
    for item in filter(None, rest.split(";")):
        k, v = item.split("=")
        opts[k] = int(v) if v.lstrip("-").isdigit() else v
    return backend, opts


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KB


def _ms(xs: list[float]) -> float:
    return 1e3 * statistics.median(xs)


def _p99(xs: list[float]) -> float:
    """The 99th percentile in ms (nearest rank)."""
    return 1e3 * percentile(xs, 99)


def worker(variant: str, m: int, adds: int, queries: int) -> dict:
    """Build one map of ``m`` environments and time it (runs inside the limited subprocess)."""
    backend, opts = parse_variant(variant)
    E, MU, VAR = smooth_data(m + adds + queries, WEIGHTS)
    Q = E[m + adds :]  # (queries, d) unseen environments
    make_env_map(backend, ALPHA, **opts).fit(E[:40], MU[:40], VAR[:40]).predict(
        Q[:2]
    )  # first-call overheads
    if backend == "torch" and "nearest_k" not in opts:
        opts.setdefault(
            "capacity", m + adds
        )  # room for the adds: no regrowth of the (N, cap, cap) factors
    rss0 = _rss_mb()
    with Stopwatch() as sw:
        gp = make_env_map(backend, ALPHA, **opts).fit(E[:m], MU[:m], VAR[:m])
        gp.predict_mean(Q[:1])  # gpytorch solves lazily: a map is built once it has answered
    build = ([sw.wall], [sw.cpu])
    mean_t = per_item(lambda i: gp.predict_mean(Q[i : i + 1]), range(queries), 5.0)
    var_t = per_item(lambda i: gp.predict(Q[i : i + 1]), range(queries), 20.0)
    batch_t = per_item(lambda _: gp.predict(Q), [0], 0.0)  # the loop's way: all queries in one call
    add_t = per_item(
        lambda i: gp.add(E[i : i + 1], MU[i : i + 1], VAR[i : i + 1]), range(m, m + adds), 30.0
    )
    gp.predict(Q[:1])  # the query after the adds (gpytorch's deferred solve) counts in the peak
    return {
        "variant": variant,
        "M": m,
        "build_s": build[0][0],
        "build_cpu_s": build[1][0],
        "mean_ms": _ms(mean_t[0]),
        "mean_cpu_ms": _ms(mean_t[1]),
        "mean_var_ms": _ms(var_t[0]),
        "mean_var_cpu_ms": _ms(var_t[1]),
        "batch_ms": _ms(batch_t[0]) / queries,
        "batch_cpu_ms": _ms(batch_t[1]) / queries,
        "add_ms": _ms(add_t[0]),
        "add_cpu_ms": _ms(add_t[1]),
        "add_p99_ms": _p99(add_t[0]),
        "add_p99_cpu_ms": _p99(add_t[1]),
        "add_max_ms": 1e3 * max(add_t[0]),
        "add_max_cpu_ms": 1e3 * max(add_t[1]),
        "adds": len(add_t[0]),
        "rss_before_mb": rss0,
        "peak_rss_mb": _rss_mb(),
        "threads": torch.get_num_threads(),
    }


def growth(variant: str, sizes: list[int]) -> list[dict]:
    """Fit ``sizes[0]`` environments, then add one at a time up to ``sizes[-1]``, timing every add;
    one row per range ``sizes[i] .. sizes[i + 1]`` (runs inside the limited subprocess)."""
    backend, opts = parse_variant(variant)
    E, MU, VAR = smooth_data(sizes[-1] + 1, WEIGHTS)
    gp = make_env_map(backend, ALPHA, **opts).fit(E[: sizes[0]], MU[: sizes[0]], VAR[: sizes[0]])
    wall, cpu = per_item(  # per add, seconds
        lambda i: gp.add(E[i : i + 1], MU[i : i + 1], VAR[i : i + 1]),
        range(sizes[0], sizes[-1]),
        float("inf"),
    )
    Q = smooth_data(50, WEIGHTS, seed=1)[0]  # (50, d) unseen environments
    query = per_item(
        lambda i: gp.predict(Q[i : i + 1]), range(50), 20.0
    )  # on the grown map: its many trees
    rows = []
    for lo, hi in zip(sizes, sizes[1:]):
        w, c = wall[lo - sizes[0] : hi - sizes[0]], cpu[lo - sizes[0] : hi - sizes[0]]
        worst = max(range(len(c)), key=c.__getitem__)
        rows.append(
            {
                "variant": variant,
                "from": lo,
                "to": hi,
                "adds": len(c),
                "add_cpu_ms": _ms(c),
                "add_p99_cpu_ms": _p99(c),
                "add_max_cpu_ms": 1e3 * c[worst],
                "worst_at_M": lo + worst,
                "add_ms": _ms(w),
                "add_p99_ms": _p99(w),
                "add_max_ms": 1e3 * max(w),
                "total_cpu_s": sum(c),
                "peak_rss_mb": _rss_mb(),
                "threads": torch.get_num_threads(),
                "final_mean_var_cpu_ms": _ms(query[1]),
                "final_mean_var_ms": _ms(query[0]),
            }
        )
    return rows


def growth_table(rows: list[dict]) -> str:
    """Markdown: CPU ms (wall ms) per range of M."""
    out = [
        "| map | M | adds | median add (ms) | p99 add (ms) | worst add (ms) | worst at M | peak "
        "RSS (MB) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "failed" in r:
            out.append(f"| {r['variant']} | | | {r['failed']} | | | | |")
            continue
        t = {
            k: f"{r[k.replace('_ms', '_cpu_ms')]:.3g} ({r[k]:.3g})"
            for k in ("add_ms", "add_p99_ms", "add_max_ms")
        }
        out.append(
            f"| {r['variant']} | {r['from']:,} to {r['to']:,} | {r['adds']:,} | {t['add_ms']} | "
            f"{t['add_p99_ms']} | {t['add_max_ms']} | {r['worst_at_M']:,} | "
            f"{r['peak_rss_mb']:,.0f} |"
        )
    finals = {r["variant"]: r for r in rows if "final_mean_var_cpu_ms" in r}
    out += [
        f"\n{v}: one mean + var query on the grown map {r['final_mean_var_cpu_ms']:.3g} ms CPU "
        f"({r['final_mean_var_ms']:.3g} ms wall)"
        for v, r in finals.items()
    ]
    return "\n".join(out)


def run_limited(variant: str, m, args):
    """:func:`worker` in a subprocess under ``RLIMIT_AS``; out of memory / time are results too."""
    limit = int(args.limit_gb * 2**30)

    def limit_memory():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    cmd = [
        sys.executable,
        __file__,
        "--worker",
        variant,
        "--sizes",
        str(m),
        "--threads",
        str(args.threads),
        "--adds",
        str(args.adds),
        "--queries",
        str(args.queries),
    ] + (["--growth"] if args.growth else [])
    try:
        out = subprocess.run(
            cmd, capture_output=True, text=True, timeout=args.timeout, preexec_fn=limit_memory
        )
    except subprocess.TimeoutExpired:
        return {"variant": variant, "M": m, "failed": f"over {args.timeout:.0f} s"}
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith(("{", "["))]
    if out.returncode == 0 and lines:
        return json.loads(lines[-1])  # growth: a list of rows
    err = out.stderr.strip().splitlines()[-1:] or [f"exit {out.returncode}"]
    oom = any(
        w in out.stderr
        for w in ("MemoryError", "can't allocate memory", "std::bad_alloc", "out of memory")
    )
    return {
        "variant": variant,
        "M": m,
        "failed": f"out of memory (> {args.limit_gb:g} GB)" if oom else err[0][:120],
    }


def search(sizes: list[int], k: int = 32) -> None:
    """The sparse map's neighbour search alone (k + 8 candidates, exact ranking): one query and
    200 queries at once, each index kind, CPU ms (medians)."""
    print("| M | d | index | one query (ms CPU) | 200 queries (ms CPU) |\n|---|---|---|---|---|")
    for d in (4, 6):
        for m in sizes:
            E = smooth_data(m + 200, 1, d=d)[0]
            for kind in INDEX_KINDS:
                index = NeighbourIndex(d, kind=kind)
                index.add(E[:m])
                one = per_item(lambda i: index.query(E[m + i : m + i + 1], k), range(200), 5.0)[1]
                many = per_item(lambda _: index.query(E[m:], k), range(5), 5.0)[1]
                print(f"| {m:,} | {d} | {kind} | {_ms(one):.3g} | {_ms(many):.3g} |", flush=True)


def table(rows: list[dict]) -> str:
    """Markdown; times as ``wall (CPU)``, medians, except the p99 and worst add."""
    head = (
        "| map | M | peak RSS (MB) | build (s) | add one (ms) | p99 add (ms) | worst add (ms) | "
        "mean (ms) "
        "| mean + var (ms) | mean + var in a batch (ms per query) "
        "|\n|---|---|---|---|---|---|---|---|---|---|"
    )
    out = [head]

    def t(key: str, fmt: str = ".3g") -> str:
        return f"{r[key]:{fmt}} ({r[key.replace('_ms', '_cpu_ms').replace('_s', '_cpu_s')]:{fmt}})"

    for r in rows:
        if "failed" in r:
            out.append(f"| {r['variant']} | {r['M']:,} | {r['failed']} | | | | | | | |")
        else:
            out.append(
                f"| {r['variant']} | {r['M']:,} | {r['peak_rss_mb']:,.0f} | {t('build_s')} | "
                f"{t('add_ms')} | "
                f"{t('add_p99_ms')} | {t('add_max_ms')} | {t('mean_ms')} | {t('mean_var_ms')} | "
                f"{t('batch_ms')} |"
            )
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,5000,20000,100000")
    ap.add_argument(
        "--variants", default=VARIANTS, help="backend[:option=value;...], comma-separated"
    )
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument(
        "--limit-gb", type=float, default=8.0, help="address-space limit of each subprocess"
    )
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per (variant, M)")
    ap.add_argument("--adds", type=int, default=20)
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--json", default=None, help="also write the rows to this file")
    ap.add_argument("--search", action="store_true", help="time the neighbour search alone")
    ap.add_argument(
        "--growth", action="store_true", help="time every add from the first size to the last"
    )
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.worker:
        rows = (
            growth(args.worker, sizes)
            if args.growth
            else worker(args.worker, sizes[0], args.adds, args.queries)
        )
        print(json.dumps(rows), flush=True)
        return
    if args.growth:
        rows = []
        for variant in args.variants.split(","):
            got = run_limited(variant, args.sizes, args)
            rows += got if isinstance(got, list) else [got]
            print(json.dumps(got), flush=True)
        print(
            f"\nthreads={args.threads}, address-space limit {args.limit_gb:g} GB, N={WEIGHTS}, d="
            f"{ENV_DIM}; "
            f"CPU ms (wall ms) per add\n\n{growth_table(rows)}"
        )
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
        return
    if args.search:
        search(sizes)
        return
    rows, dead = [], set()
    for variant in args.variants.split(","):
        for m in sizes:
            r = (
                {"variant": variant, "M": m, "failed": "not tried (failed at a smaller M)"}
                if variant in dead
                else run_limited(variant, m, args)
            )
            if "failed" in r:
                dead.add(variant)
            rows.append(r)
            print(json.dumps(r), flush=True)
    print(
        f"\nthreads={args.threads}, address-space limit {args.limit_gb:g} GB per map, N={WEIGHTS}, "
        f"d={ENV_DIM}, "
        f"alpha={ALPHA:g}\n"
    )
    print(table(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
