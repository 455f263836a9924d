"""Experiments as plain functions ``run(out_dir, **settings) -> metrics``; no Hydra here.

:func:`run_experiment` takes a plain dict (the resolved Hydra config, or one built by hand),
runs the named experiment and writes ``metrics.json`` and ``config.yaml``-independent outputs
into ``out_dir``.
"""

from __future__ import annotations

import inspect
import os
import re
import socket
import time
import traceback
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from . import arm_reach, beam_window, fig3_toy, fig4_window, point_particle
from ..threads import torch_threads
from .common import metric_value, resolve_device, resolve_dtype, write_json
from .run_folder import check_run_folder, write_status
from .summary import build_summary

EXPERIMENTS: dict[str, Callable[..., dict]] = {
    "fig3_toy": fig3_toy.run,
    "fig4_window": fig4_window.run,
    "point_particle": point_particle.run,
    "beam_window": beam_window.run,
    "arm_reach": arm_reach.run,
}

_DOTTED = re.compile(r"[A-Za-z_][\w-]*(\.[\w-]+)*")

__all__ = ["EXPERIMENTS", "run_experiment", "metric_value"]


def run_experiment(cfg: dict, out_dir: str | Path) -> dict:
    """Run ``cfg["name"]`` with the settings of ``cfg["settings"]`` plus the shared ``seed``,
    ``device``, ``dtype`` and ``optimizer`` entries (and the top-level ``task``, ``gp`` and
    ``resume`` where the experiment takes them), with ``cfg["threads"]`` torch threads
    (:func:`~protorch.threads.torch_threads`; ``None`` leaves torch's setting); write
    ``metrics.json`` with its headline numbers under ``"summary"``
    (:mod:`~protorch.experiments.summary`) and ``status.json`` (``running``, then ``ok`` or
    ``failed`` with the error); return the metrics. A folder holding another experiment's results
    is refused before any work (:func:`~protorch.experiments.run_folder.check_run_folder`).

    ``cfg["objective"]``, a dotted metrics key such as ``"test.success_rate"`` (or ``None``), names
    the number a hyperparameter sweeper optimises: it is stored as
    ``metrics["objective"] = {"metric": key, "value": float}`` and the Hydra app returns it.
    """
    name = cfg.get("name")
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {sorted(EXPERIMENTS)}")
    objective = cfg.get("objective")
    if objective is not None and not (isinstance(objective, str) and _DOTTED.fullmatch(objective)):
        raise ValueError(f"objective must be a dotted metrics key such as 'test.success_rate' or null, "
                         f"got {objective!r}")
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
    check_run_folder(out_dir, name)  # another experiment's results are refused before any work
    out_dir.mkdir(parents=True, exist_ok=True)
    # provenance, so a sweep's report can tell where and when each run ran (host, process)
    run_info = {"host": socket.gethostname(), "pid": os.getpid(),
                "started": datetime.now(timezone.utc).isoformat(timespec="milliseconds")}
    t0 = time.perf_counter()
    try:
        with torch_threads(cfg.get("threads")):
            write_status(out_dir, name, "running")
            metrics = fn(
                out_dir,
                seed=int(cfg.get("seed", 0)),
                device=resolve_device(cfg.get("device", "cpu")),
                dtype=resolve_dtype(cfg.get("dtype", "float64")),
                optimizer=opt,
                plot=bool(cfg.get("plot", True)),
                **settings,
            )
    except BaseException as exc:  # the folder says the run failed, and why
        error = f"{type(exc).__name__}: {exc}"
        summary = build_summary(name, {}, run_dir=out_dir, wall_seconds=time.perf_counter() - t0,
                                status="failed", error=error)
        write_status(out_dir, name, "failed", error=error, traceback=traceback.format_exc(), summary=summary)
        raise
    run_info["finished"] = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    metrics = {"experiment": name, **metrics, "run": run_info}
    try:
        if objective is not None:
            metrics["objective"] = {"metric": objective, "value": metric_value(metrics, objective)}
    finally:  # the run's results are kept even when the objective key is wrong
        metrics["summary"] = build_summary(name, metrics, run_dir=out_dir, wall_seconds=time.perf_counter() - t0)
        write_json(out_dir / "metrics.json", metrics)
        write_status(out_dir, name, "ok", summary=metrics["summary"])
    return metrics
