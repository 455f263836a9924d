"""Experiments as plain functions ``run(out_dir, **settings) -> metrics``; no Hydra here.

:func:`run_experiment` takes a plain dict (the resolved Hydra config, or one built by hand),
runs the named experiment and writes ``metrics.json`` and ``config.yaml``-independent outputs
into ``out_dir``.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Callable

from . import arm_reach, fig3_toy, fig4_window, point_particle
from .common import resolve_device, resolve_dtype, write_json

EXPERIMENTS: dict[str, Callable[..., dict]] = {
    "fig3_toy": fig3_toy.run,
    "fig4_window": fig4_window.run,
    "point_particle": point_particle.run,
    "arm_reach": arm_reach.run,
}

__all__ = ["EXPERIMENTS", "run_experiment"]


def run_experiment(cfg: dict, out_dir: str | Path) -> dict:
    """Run ``cfg["name"]`` with the settings of ``cfg["settings"]`` plus the shared ``seed``,
    ``device``, ``dtype`` and ``optimizer`` entries (and the top-level ``task``, ``gp`` and
    ``resume`` where the experiment takes them); write ``metrics.json``; return the metrics."""
    name = cfg.get("name")
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {sorted(EXPERIMENTS)}")
    opt = dict(cfg.get("optimizer") or {})
    if "beta" not in opt or not float(opt["beta"]) > 0:
        raise ValueError(f"optimizer.beta must be > 0, got {opt.get('beta')}")
    fn = EXPERIMENTS[name]
    accepted = inspect.signature(fn).parameters
    settings = dict(cfg.get("settings") or {})
    # top-level groups (``task.demos=...``, ``gp.alpha=...`` on the command line) overlay the
    # experiment's own settings of the same name; empty ones are not passed at all
    for key in ("task", "gp"):
        top = dict(cfg.get(key) or {})
        if top:
            if key not in accepted:
                raise ValueError(f"experiment {name!r} takes no {key}.* settings, got {sorted(top)}")
            settings[key] = {**dict(settings.get(key) or {}), **top}
    if cfg.get("resume", False):
        if "resume" not in accepted:
            raise ValueError(f"experiment {name!r} cannot resume (resume=true); run it again instead")
        settings["resume"] = True
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    metrics = fn(
        out_dir,
        seed=int(cfg.get("seed", 0)),
        device=resolve_device(cfg.get("device", "cpu")),
        dtype=resolve_dtype(cfg.get("dtype", "float64")),
        optimizer=opt,
        plot=bool(cfg.get("plot", True)),
        **settings,
    )
    metrics = {"experiment": name, **metrics}
    write_json(out_dir / "metrics.json", metrics)
    return metrics
