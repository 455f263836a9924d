"""The README's main job (``python -m protorch experiment=point_particle``) timed phase by phase,
side by side with another checkout (run on demand).

    python benchmarks/main_job.py [--against DIR] [--repeats 2] [--threads auto] [override ...]

Each run is a fresh Python process that composes the app's config (``benchmarks/configs.py``),
runs :func:`protorch.experiments.run_experiment` into a temporary folder and times the
experiment's phases by wrapping its methods: wall seconds, and CPU seconds of the process and
of the children it waited for (a loop baseline's worker process is counted in the phase that
waits for it). ``startup`` is the process's time before the experiment starts (interpreter,
imports, config). With ``--against DIR`` (a checkout of another version, e.g. ``git worktree
add /tmp/base main``) the runs alternate between this checkout and ``DIR`` so that both see the
same load; the table gives the median of each and the ratio, and every run's ``metrics.json``
is compared with the first run of this checkout key by key (timing keys aside): the lines
printed name every key that differs. ``--quick`` runs a reduced budget (100 loop
environments, 20 held-out, 10 moving episodes), a check that the benchmark works.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
QUICK = [
    "settings.loop.num_envs=100",
    "settings.test.num_envs=20",
    "settings.dynamic.episodes=10",
    "settings.dynamic_paper.episodes=10",
]
TIMING = ("seconds", "wall", "started", "finished", "pid", "host", "run_dir")
PHASES = ("startup", "demos_only", "loop", "evaluation", "authors_test", "rwr", "figures", "total")

CHILD = r"""
import json, resource, sys, time
t_start = time.perf_counter()
tree, out, overrides = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
sys.path[:0] = [tree, tree + "/benchmarks"]
def cpu():
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime
import protorch.experiments.point_particle as pp
import protorch.experiments.loop_run as si
from configs import experiment_config
from protorch.experiments import run_experiment
spent, inside = {}, []
def timed(cls, name, key):
    orig = getattr(cls, name)
    def wrapper(self, *a, **k):
        label = key(a) if callable(key) else key
        # counted in the phase that called it (a baseline's own evaluation)
        if inside or label is None:
            return orig(self, *a, **k)
        inside.append(label)
        w, c = time.perf_counter(), cpu()
        try:
            return orig(self, *a, **k)
        finally:
            inside.pop()
            old = spent.get(label, (0.0, 0.0))
            spent[label] = (old[0] + time.perf_counter() - w, old[1] + cpu() - c)
    setattr(cls, name, wrapper)
timed(si.SelfImprovementExperiment, "run_baseline", lambda a: a[0])
timed(si.SelfImprovementExperiment, "run_loop", lambda a: "loop" if not a or a[0] is None else None)
timed(si.SelfImprovementExperiment, "evaluate", "evaluation")
timed(pp.PointParticleExperiment, "extra_tests", "authors_test")
timed(pp.PointParticleExperiment, "figures", "figures")
cfg = experiment_config("point_particle", ["settings.progress=false", *overrides])
w0, c0 = time.perf_counter(), cpu()
spent["startup"] = (w0 - t_start, c0)
run_experiment(cfg, out)
spent["total"] = (time.perf_counter() - t_start, cpu())
print(json.dumps(spent))
"""


def run_once(tree: Path, overrides: list[str]) -> tuple[dict, dict]:
    """Phase seconds ``{phase: (wall, cpu)}`` and the metrics of one run of ``tree``'s code."""
    with tempfile.TemporaryDirectory(prefix="main_job_") as tmp:
        out = Path(tmp) / "run"
        env = {**os.environ, "PYTHONPATH": str(tree)}
        res = subprocess.run(
            [sys.executable, "-c", CHILD, str(tree), str(out), json.dumps(overrides)],
            env=env,
            capture_output=True,
            text=True,
            cwd=tree,
        )
        if res.returncode != 0:
            raise RuntimeError(f"the run of {tree} failed:\n{res.stderr[-3000:]}")
        spent = {k: tuple(v) for k, v in json.loads(res.stdout.strip().splitlines()[-1]).items()}
        metrics = json.loads((out / "metrics.json").read_text())
    return spent, metrics


def flatten(d, prefix=""):
    out = {}
    for k, v in d.items() if isinstance(d, dict) else enumerate(d):
        key = f"{prefix}.{k}" if prefix else str(k)
        out.update(flatten(v, key) if isinstance(v, (dict, list)) else {key: v})
    return out


def differences(a: dict, b: dict) -> list[str]:
    fa, fb = flatten(a), flatten(b)
    out = []
    for k in sorted(set(fa) | set(fb)):
        if any(t in k for t in TIMING) or k.startswith("run."):
            continue
        x, y = fa.get(k, "<missing>"), fb.get(k, "<missing>")
        if x != y and not (
            isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)
        ):
            out.append(f"{k}: {x!r} != {y!r}")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--against", type=Path, default=None, help="another checkout to time side by side"
    )
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--threads", default="auto", help="the app's threads setting (auto, 1, 2, ...)")
    p.add_argument(
        "--quick", action="store_true", help="a reduced budget: a check that the benchmark runs"
    )
    p.add_argument(
        "overrides", nargs="*", help="more config overrides, as on the app's command line"
    )
    args = p.parse_args()
    overrides = [f"threads={args.threads}", *(QUICK if args.quick else []), *args.overrides]
    trees = {"this": HERE.parent} | ({"against": args.against.resolve()} if args.against else {})
    runs = {name: [] for name in trees}
    reference = None
    print(f"main job, overrides {' '.join(overrides)}; load average before: {os.getloadavg()}")
    for r in range(args.repeats):
        for name, tree in trees.items():
            spent, metrics = run_once(tree, overrides)
            runs[name].append(spent)
            reference = reference or metrics
            diff = differences(reference, metrics)
            print(
                f"run {r + 1} {name}: {spent['total'][0]:.1f} s wall, {spent['total'][1]:.1f} s "
                "CPU, load "
                f"{os.getloadavg()[0]:.1f}; metrics vs the first run: {len(diff)} keys differ",
                flush=True,
            )
            for line in diff:
                print("   ", line)
    print(
        "\n| phase | "
        + " | ".join(f"{n}: wall / CPU s" for n in trees)
        + (" | against / this: wall, CPU |" if args.against else " |")
    )
    print("|---|" + "---|" * (len(trees) + bool(args.against)))
    for phase in PHASES:
        med = {
            n: [statistics.median(s.get(phase, (0.0, 0.0))[i] for s in runs[n]) for i in (0, 1)]
            for n in trees
        }
        cells = " | ".join(f"{med[n][0]:.1f} / {med[n][1]:.1f}" for n in trees)
        ratio = (
            f" | {med['against'][0] / med['this'][0]:.2f}x, "
            f"{med['against'][1] / max(med['this'][1], 1e-9):.2f}x |"
            if args.against and med["this"][0] > 0
            else " |"
        )
        print(f"| {phase} | {cells}{ratio}")


if __name__ == "__main__":
    main()
