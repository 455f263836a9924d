"""Experiments as plain functions ``run(out_dir, **settings) -> metrics``; no Hydra here.

:func:`run_experiment` takes a plain dict (the resolved Hydra config, or one built by hand),
checks every setting against its typed schema (:mod:`protorch.experiments.settings`; a bad one
raises :class:`SettingsError` with one line, before any work), runs the named experiment and
writes ``metrics.json`` into ``out_dir``.
"""

from __future__ import annotations

import copy
import inspect
import os
import re
import socket
import time
import traceback
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from ..data.files import atomic_write_bytes
from ..gp import BACKENDS
from ..optim import OPTIMIZERS, BaseOptimizer
from ..tasks import TaskContractError, task_class
from ..threads import torch_threads
from .common import metric_value, per_method_form, resolve_device, resolve_dtype, write_json
from .policy_record import write_policy_record
from .registry import REGISTRY, Experiment, experiment
from .run_folder import STATUS_FILE, check_run_folder, write_config, write_status
from .settings import GP, OPTIMIZER_SCHEMAS, SettingsError, validate
from .summary import baseline_settings, build_summary

# name -> run(out_dir, **settings) -> metrics, of every registered experiment (registry.REGISTRY)
EXPERIMENTS: dict[str, Callable[..., dict]] = {name: e.run for name, e in REGISTRY.items()}

_DOTTED = re.compile(r"[A-Za-z_][\w-]*(\.[\w-]+)*")

# a value refused before any work: a setting (checked against its schema) or what a task's costs or
# success return (checked on the demonstrations); the app prints its one line, with no traceback
REFUSED = (SettingsError, TaskContractError)

__all__ = [
    "EXPERIMENTS",
    "REGISTRY",
    "run_experiment",
    "check_config",
    "metric_value",
    "SettingsError",
    "TaskContractError",
    "REFUSED",
]


def _check_optimizer_group(group: dict, where: str) -> dict:
    name = group.get("name")
    if name not in OPTIMIZERS:
        raise SettingsError(f"{where}.name={name!r} must be one of {', '.join(sorted(OPTIMIZERS))}")
    if name in OPTIMIZER_SCHEMAS:
        return validate(OPTIMIZER_SCHEMAS[name], group, where)
    cls = OPTIMIZERS[name]  # a registered optimiser without a schema: its keyword arguments
    known = {p for c in (cls, BaseOptimizer) for p in inspect.signature(c.__init__).parameters} - {
        "self",
        "mean",
        "var",
    }
    unknown = sorted(set(group) - known - {"name"})
    if unknown:
        raise SettingsError(f"{where}.{unknown[0]} is not a setting of optimizer {name!r}")
    return group


def _check_task(exp: type[Experiment], task: dict) -> dict:
    target = task.pop("_target_", None)
    if exp.task is not None:
        expected = exp.task
        if target is not None:
            try:
                cls = task_class(target)
            except ValueError as exc:
                raise SettingsError(str(exc)) from None
            if cls is not expected:
                raise SettingsError(
                    f"task._target_={target!r}: experiment {exp.name!r} runs "
                    f"{expected.__module__}.{expected.__name__}; run your own task with "
                    "experiment=self_improve"
                )
        return validate(exp.task_schema, task, "task") if exp.task_schema else task
    if target in (None, "???"):
        raise SettingsError(
            "task._target_ must name the task class, e.g. task._target_=my_module.MyTask"
        )
    return {"_target_": target, **task}


def check_config(cfg: dict) -> dict:
    """Every setting of ``cfg`` checked (types, ranges, names) before any work: the keyword
    arguments of the experiment function (``out_dir`` aside). Raises :class:`SettingsError`."""
    name = cfg.get("name")
    exp = experiment(name)  # SettingsError naming the experiments
    objective = cfg.get("objective")
    if objective is not None and not (isinstance(objective, str) and _DOTTED.fullmatch(objective)):
        raise SettingsError(
            f"objective={objective!r} must be a dotted metrics key such as 'test.success_rate' or "
            "null"
        )
    threads = cfg.get("threads", "auto")
    if not (
        threads is None
        or threads == "auto"
        or (isinstance(threads, int) and not isinstance(threads, bool) and threads >= 0)
    ):
        raise SettingsError(f"threads={threads!r} must be auto, an int >= 1 or null")
    seed = cfg.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SettingsError(f"seed={seed!r} must be an int >= 0")
    for key in ("plot", "resume"):
        if not isinstance(cfg.get(key, key == "plot"), bool):
            raise SettingsError(f"{key}={cfg.get(key)!r} must be true or false")
    try:
        device, dtype = (
            resolve_device(cfg.get("device", "cpu")),
            resolve_dtype(cfg.get("dtype", "float64")),
        )
    except (ValueError, RuntimeError) as exc:
        raise SettingsError(f"device / dtype: {exc}") from None
    accepted = inspect.signature(exp.run).parameters
    opt = _check_optimizer_group(
        {"name": "pro", **dict(cfg.get("optimizer") or {})}, "optimizer"
    )  # PRO unless named
    base = cfg.get("baseline_optimizer")
    base = None if base is None else _check_optimizer_group(dict(base), "baseline_optimizer")
    settings = dict(cfg.get("settings") or {})
    if exp.settings_schema is not None:
        validate(exp.settings_schema, settings, "settings")
    exp.check_settings(cfg, settings)
    gp = dict(cfg.get("gp") or {})
    if gp:
        validate(GP, gp, "gp")
        if gp.get("backend", "torch") not in BACKENDS:
            raise SettingsError(
                f"gp.backend={gp['backend']!r} must be one of {', '.join(sorted(BACKENDS))}"
            )
    task = _check_task(exp, dict(cfg.get("task") or {}))
    # top-level groups (``task.demos=...``, ``gp.alpha=...``) overlay the experiment's own settings
    for key, top in (("task", task), ("gp", gp)):
        if top:
            if key not in accepted:
                raise SettingsError(
                    f"experiment {name!r} takes no {key}.* settings, got {', '.join(sorted(top))}"
                )
            settings[key] = {**dict(settings.get(key) or {}), **top}
    exp.take_robot(cfg.get("robot"), settings, dict(settings.get("task") or {}))
    if cfg.get("resume", False):
        if "resume" not in accepted:
            raise SettingsError(
                f"resume=true: experiment {name!r} cannot resume; run it again instead"
            )
        settings["resume"] = True
    if exp.group_optimizer:
        settings["optimizer"] = opt
        if base is not None and "baseline_optimizer" in accepted:
            settings["baseline_optimizer"] = base
    else:
        settings["optimizer"] = per_method_form(opt, base)
    return dict(
        seed=int(seed), device=device, dtype=dtype, plot=bool(cfg.get("plot", True)), **settings
    )


def run_experiment(cfg: dict, out_dir: str | Path) -> dict:
    """Check ``cfg`` (:func:`check_config`), run ``cfg["name"]`` into ``out_dir`` with
    ``cfg["threads"]`` torch threads (:func:`~protorch.threads.torch_threads`; ``None`` leaves
    torch's setting), write ``metrics.json`` with its headline numbers under ``"summary"``
    (:mod:`~protorch.experiments.summary`) and ``status.json`` (``running``, then ``ok`` or
    ``failed`` with the error); return the metrics. A folder holding another experiment's results
    is refused before any work (:func:`~protorch.experiments.run_folder.check_run_folder`), and a
    value refused by the experiment before its work (:data:`REFUSED`, e.g. a task whose ``costs``
    returns the wrong shape) leaves a folder this call found empty as it was.

    ``cfg``: ``name``, ``seed``, ``device``, ``dtype``, ``plot``, ``resume``, the ``optimizer``
    group (``{"name": "pro", "beta": ..., ...}``, conf/optimizer/), ``baseline_optimizer`` (the
    comparison some experiments run), ``gp`` and ``task`` (overlaid on the experiment's settings
    of the same name) and ``settings`` (the experiment function's own keyword arguments).
    ``cfg["objective"]``, a dotted metrics key such as ``"test.success_rate"`` (or ``None``), names
    the number a hyperparameter sweeper optimises: it is stored as
    ``metrics["objective"] = {"metric": key, "value": float}`` and the Hydra app returns it.
    """
    kwargs = check_config(cfg)
    record_kwargs = copy.deepcopy(kwargs)  # the settings as checked, for policy.json
    name, objective = cfg["name"], cfg.get("objective")
    out_dir = Path(out_dir)
    check_run_folder(out_dir, name)  # another experiment's results are refused before any work
    created = not out_dir.exists()
    status_before = (
        (out_dir / STATUS_FILE).read_bytes() if (out_dir / STATUS_FILE).is_file() else None
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    baseline = baseline_settings(cfg.get("optimizer"), cfg.get("baseline_optimizer"))
    # provenance, so a sweep's report can tell where and when each run ran (host, process)
    run_info = {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "started": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
    }
    t0 = time.perf_counter()
    try:
        with torch_threads(cfg.get("threads")):
            write_status(out_dir, name, "running")
            metrics = EXPERIMENTS[name](out_dir, **kwargs)
    except REFUSED:  # refused before any work: the folder is left as it was found
        if status_before is None:
            (out_dir / STATUS_FILE).unlink(missing_ok=True)
        else:
            atomic_write_bytes(out_dir / STATUS_FILE, status_before)
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()
        raise
    except BaseException as exc:  # the folder says the run failed, and why
        error = f"{type(exc).__name__}: {exc}"
        summary = build_summary(
            name,
            {},
            run_dir=out_dir,
            wall_seconds=time.perf_counter() - t0,
            status="failed",
            error=error,
        )
        write_status(
            out_dir, name, "failed", error=error, traceback=traceback.format_exc(), summary=summary
        )
        raise
    run_info["finished"] = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    write_config(out_dir, cfg)  # the run's settings (the app wrote them already)
    metrics = {"experiment": name, **metrics, "run": run_info}
    try:
        if objective is not None:
            metrics["objective"] = {"metric": objective, "value": metric_value(metrics, objective)}
    finally:  # the run's results are kept even when the objective key is wrong
        metrics["summary"] = build_summary(
            name, metrics, run_dir=out_dir, wall_seconds=time.perf_counter() - t0, baseline=baseline
        )
        write_json(out_dir / "metrics.json", metrics)
        write_status(out_dir, name, "ok", summary=metrics["summary"])
    write_policy_record(out_dir, name, record_kwargs)  # what protorch.load builds the policy from
    return metrics
