"""Experiments as plain functions ``run(out_dir, **settings) -> metrics``; no Hydra here.

:func:`run_experiment` takes a plain dict (the resolved Hydra config, or one built by hand),
runs the named experiment and writes ``metrics.json`` and ``config.yaml``-independent outputs
into ``out_dir``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from . import fig3_toy, fig4_window
from .common import resolve_device, resolve_dtype, write_json

EXPERIMENTS: dict[str, Callable[..., dict]] = {
    "fig3_toy": fig3_toy.run,
    "fig4_window": fig4_window.run,
}

__all__ = ["EXPERIMENTS", "run_experiment"]


def run_experiment(cfg: dict, out_dir: str | Path) -> dict:
    """Run ``cfg["name"]`` with the settings of ``cfg["settings"]`` plus the shared ``seed``,
    ``device``, ``dtype`` and ``optimizer`` entries; write ``metrics.json``; return the metrics."""
    name = cfg.get("name")
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {sorted(EXPERIMENTS)}")
    opt = dict(cfg.get("optimizer") or {})
    if "beta" not in opt or not float(opt["beta"]) > 0:
        raise ValueError(f"optimizer.beta must be > 0, got {opt.get('beta')}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    metrics = EXPERIMENTS[name](
        out_dir,
        seed=int(cfg.get("seed", 0)),
        device=resolve_device(cfg.get("device", "cpu")),
        dtype=resolve_dtype(cfg.get("dtype", "float64")),
        optimizer=opt,
        plot=bool(cfg.get("plot", True)),
        **dict(cfg.get("settings") or {}),
    )
    metrics = {"experiment": name, **metrics}
    write_json(out_dir / "metrics.json", metrics)
    return metrics
