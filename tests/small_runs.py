"""Small runs of the self-improvement experiments whose every metric (timings aside) two
environments must agree on: ``python -m tests.small_runs NAME THREADS`` prints them as JSON, with
a hash of each checkpoint's tensors (the loops' data sets, bit for bit)."""

from __future__ import annotations

import hashlib
import json
import math
import sys
import tempfile
from pathlib import Path

from safetensors.torch import load_file

from protorch.experiments import run_experiment
from protorch.experiments.common import flatten_metrics

SMALL = {
    "arm_reach": {
        "optimizer": {
            "name": "pro",
            "beta": 200.0,
            "max_iter": 10,
            "num_samples": 40,
            "relevance_samples": 40,
        },
        "gp": {"backend": "torch", "alpha": 30.0, "var_floor": 1e-3, "nearest_k": 30},
        "task": {"_target_": "protorch.tasks.ArmReachTask", "priors": 200, "demo_envs": 6},
        "settings": {
            "loop": {"num_envs": 40, "batch_size": 20},
            "test": {"num_envs": 40},
            "dynamic": {"episodes": 6},
            "baselines": ["labels_off"],
            "progress": False,
        },
    },
    "point_particle": {
        "optimizer": {
            "name": "pro",
            "beta": 20.0,
            "max_iter": 15,
            "num_samples": 30,
            "relevance_samples": 30,
        },
        "baseline_optimizer": {"name": "rwr", "beta": 20.0, "num_samples": 30, "max_iter": 15},
        "gp": {"backend": "torch", "alpha": 1e-3, "var_floor": 1e-4},
        "task": {"_target_": "protorch.tasks.PointParticleTask", "demo_envs": 10},
        "settings": {
            "loop": {"num_envs": 40, "batch_size": 20},
            "test": {"num_envs": 40},
            "dynamic": {"episodes": 6},
            "dynamic_paper": {"episodes": 6},
            "baselines": ["demos_only", "rwr"],
            "progress": False,
        },
    },
}


def _comparable(v):
    return "nan" if isinstance(v, float) and math.isnan(v) else v


def small_run(name: str, threads: int, out_dir: Path | None = None, physics: bool = True) -> dict:
    """``{metrics key: value}`` of a small run of ``name`` at ``threads`` torch threads, timing keys
    and provenance left out, plus ``checkpoint:<folder>``: a hash of each checkpoint's tensors.
    ``physics=False``: the arm's MuJoCo episodes left out (``settings.physics.run=never``)."""
    cfg = {"name": name, "seed": 0, "threads": threads, "plot": False, **SMALL[name]}
    if not physics and name == "arm_reach":
        cfg["settings"] = {**cfg["settings"], "physics": {"run": "never"}}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(out_dir or tmp)
        m = run_experiment(cfg, out)
        flat = {
            k: _comparable(v)
            for k, v in flatten_metrics(m).items()
            if "seconds" not in k
            and k != "settings.threads"
            and not k.startswith(("run.", "summary."))
        }
        for path in sorted(out.rglob("dataset.safetensors")):
            tensors = load_file(path)
            digest = hashlib.sha256(
                b"".join(tensors[k].numpy().tobytes() for k in sorted(tensors))
            ).hexdigest()
            flat[f"checkpoint:{path.parent.parent.relative_to(out)}"] = digest[:16]
    return flat


if __name__ == "__main__":
    print(json.dumps(small_run(sys.argv[1], int(sys.argv[2]))))
