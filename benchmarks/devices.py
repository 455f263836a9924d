"""The self-improvement experiments on every available device, side by side in one run (on demand:
``python benchmarks/devices.py``).

Runs the point particle's main job (``python -m protorch experiment=point_particle``) and a
reduced arm run (:data:`RUNS`: 200 loop environments, 100 held-out, 20 moving episodes, the
MuJoCo episodes left out: MuJoCo steps on the CPU whatever ``device``) once per device and dtype,
and prints for each: the wall time, the headline metrics, and how many of the first run's
metrics (CPU, float64) the run reproduces (exactly, and within 0.05 for rates). A device other than
the
CPU draws its samples from its own random streams, so its numbers agree with the CPU's in
distribution, not bit for bit; what this checks is that every module of the run (ProMP, PRO, the
GP map and its backends, the loop, the tests, the policy) works on that device and gives
numbers of the same quality.

``--devices cpu,cuda`` (default: the CPU and CUDA where ``torch.cuda.is_available()``),
``--dtypes float64,float32`` (default float64), ``--experiments point_particle,arm_reach``,
``--threads`` (torch's
CPU threads, default 1), ``--json FILE`` (every run's metrics and seconds).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import torch
from _timing import Stopwatch
from configs import experiment_config

from protorch.experiments import run_experiment
from protorch.experiments.common import flatten_metrics

RUNS = {  # experiment: its overrides (Hydra syntax)
    "point_particle": ["settings.progress=false"],
    "arm_reach": [
        "settings.progress=false",
        "settings.loop.num_envs=200",
        "settings.test.num_envs=100",
        "settings.dynamic.episodes=20",
        "settings.baselines=[]",
        "settings.physics.run=never",
    ],
}

HEADLINES = {
    "point_particle": ("test.success_rate", "dynamic.success_rate"),
    "arm_reach": ("test.success_rate", "dynamic.success_rate"),
}


def one_run(name: str, device: str, dtype: str, threads: int) -> tuple[dict, float]:
    """The run of ``name`` (:data:`RUNS`) on ``device`` in ``dtype``: ``(flat metrics, wall
    seconds)``."""
    cfg = experiment_config(
        name,
        [
            *RUNS[name],
            f"device={device}",
            f"dtype={dtype}",
            f"threads={threads}",
            "plot=false",
            "seed=0",
        ],
    )
    with tempfile.TemporaryDirectory() as tmp:
        with Stopwatch() as sw:
            m = run_experiment(cfg, Path(tmp) / "run")
        seconds = sw.wall
    flat = {
        k: v
        for k, v in flatten_metrics(m).items()
        if "seconds" not in k and not k.startswith(("run.", "summary.", "settings."))
    }
    return flat, seconds


def agreement(ref: dict, other: dict) -> tuple[int, int, int, int]:
    """``(equal, compared, rates within 0.05, rates)`` over the numeric metrics of ``ref``
    (``compared``: those ``other`` holds too; ``rates``: the rates and successes among them)."""
    equal = n = close = rates = 0
    for k, v in ref.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        rate = "rate" in k or "success" in k
        rates += rate
        w = other.get(k)
        if not isinstance(w, (int, float)) or (isinstance(v, float) and math.isnan(v)):
            continue
        n += 1
        equal += v == w
        close += rate and abs(float(v) - float(w)) <= 0.05
    return equal, n, close, rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default = "cpu,cuda" if torch.cuda.is_available() else "cpu"
    ap.add_argument("--devices", default=default)
    ap.add_argument("--dtypes", default="float64")
    ap.add_argument("--experiments", default="point_particle,arm_reach")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    devices, dtypes = args.devices.split(","), args.dtypes.split(",")
    for d in devices:
        if d.startswith("cuda") and not torch.cuda.is_available():
            raise SystemExit(f"--devices names {d} but torch.cuda.is_available() is False")
    if torch.cuda.is_available():
        print(
            f"torch {torch.__version__}, CUDA {torch.version.cuda}, {torch.cuda.get_device_name(0)}"
        )
    out = {}
    for name in args.experiments.split(","):
        print(f"\n{name} {' '.join(RUNS[name])} (seed 0)")
        keys = HEADLINES.get(name, ())
        print(
            f"{'device':<8}{'dtype':<9}{'wall s':>9}"
            + "".join(f"{k:>24}" for k in keys)
            + f"{'equal to cpu float64':>22}{'rates within 0.05':>19}"
        )
        ref = None
        for d in devices:
            for dt in dtypes:
                flat, sec = one_run(name, d, dt, args.threads)
                ref = flat if ref is None else ref
                eq, n, close, rates = agreement(ref, flat)
                print(
                    f"{d:<8}{dt:<9}{sec:>9.1f}"
                    + "".join(f"{flat.get(k, float('nan')):>24.3f}" for k in keys)
                    + f"{f'{eq} / {n}':>22}{f'{close} / {rates}':>19}",
                    flush=True,
                )
                out[f"{name}/{d}/{dt}"] = {"seconds": sec, "metrics": flat}
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
