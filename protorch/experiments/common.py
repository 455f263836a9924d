"""Plumbing shared by the experiments: dtype names, seeding, atomic JSON output."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import torch

DTYPES = {"float32": torch.float32, "float64": torch.float64}


def resolve_dtype(name: str | torch.dtype) -> torch.dtype:
    if isinstance(name, torch.dtype):
        return name
    if name not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {name!r}")
    return DTYPES[name]


def resolve_device(name: str | torch.device) -> torch.device:
    dev = torch.device(name)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' was asked for but torch.cuda.is_available() is False")
    return dev


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as JSON atomically (temp file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def flatten_metrics(data: dict, prefix: str = "") -> dict:
    """Nested dicts -> ``{"a.b.c": leaf}``; lists and other leaves are kept as they are."""
    out: dict = {}
    for key, value in data.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten_metrics(value, path + "."))
        else:
            out[path] = value
    return out


def metric_value(metrics: dict, key: str) -> float:
    """The number at the dotted ``key`` of a (nested) metrics dict, e.g. ``"test.success_rate"``;
    a bool counts as 0 / 1. A missing or non-numeric entry raises an error listing the numeric keys."""
    node = metrics
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            node = None
            break
        node = node[part]
    if isinstance(node, (bool, int, float)) and not isinstance(node, str):
        return float(node)
    numeric = sorted(k for k, v in flatten_metrics(metrics).items() if isinstance(v, (bool, int, float)))
    what = "no such metric" if node is None else f"not a number ({type(node).__name__})"
    raise ValueError(f"objective {key!r}: {what}; numeric metrics of this run: {', '.join(numeric)}")


def optimizer_kwargs(common: dict, specific: dict | None) -> dict:
    """The shared optimiser settings (beta, num_samples, ...) overlaid with a method's own."""
    out = {k: v for k, v in common.items() if not isinstance(v, dict)}
    out.update(specific or {})
    return out
