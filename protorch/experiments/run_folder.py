"""A run folder that tells the truth: whose results it holds, and whether its run finished.

``status.json`` (written atomically) says ``running`` from the start of a run, then ``ok`` or
``failed`` with the error; :func:`check_run_folder` refuses, before any work, a folder that holds
another experiment's results (``metrics.json`` or ``status.json`` naming another experiment), so
a second run cannot replace the first one's files, and clears the temporary files a killed
atomic write left behind.
"""

from __future__ import annotations

import inspect
import json
import os
import socket
from datetime import datetime, timezone
from pathlib import Path

from ..data.files import atomic_write_bytes, remove_stale_tmp
from .common import write_json

__all__ = ["STATUS_FILE", "CONFIG_FILE", "check_run_folder", "write_status", "write_config", "rebuild_experiment",
           "load_policy", "POLICY_EXPERIMENTS"]

STATUS_FILE = "status.json"


def _owner(path: Path) -> str | None:
    """The ``experiment`` a results file names (``None``: no file, or not one of ours)."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        raise ValueError(f"{path} exists but is not readable JSON: refusing to run into {path.parent}; "
                         "choose another hydra.run.dir") from None
    return data.get("experiment") if isinstance(data, dict) else None


def check_run_folder(out_dir: str | Path, name: str) -> None:
    """Refuse ``out_dir`` if it holds another experiment's results; then remove stale ``.*.tmp``
    files there. Runs of the same experiment may reuse their folder (``resume=true`` continues
    from its checkpoint; the experiment itself refuses a checkpoint it was not asked to resume)."""
    out_dir = Path(out_dir)
    for file in ("metrics.json", STATUS_FILE):
        owner = _owner(out_dir / file)
        if owner is not None and owner != name:
            raise ValueError(
                f"{out_dir} holds results of experiment {owner!r} ({file}); refusing to write {name!r} "
                "there and replace them: choose another hydra.run.dir")
    remove_stale_tmp(out_dir)


def write_status(out_dir: str | Path, name: str, status: str, **extra) -> Path:
    """``status.json`` = ``{"experiment", "status", "host", "pid", "time", **extra}``, atomically."""
    path = Path(out_dir) / STATUS_FILE
    write_json(path, {"experiment": name, "status": status, "host": socket.gethostname(), "pid": os.getpid(),
                      "time": datetime.now(timezone.utc).isoformat(timespec="milliseconds"), **extra})
    return path


CONFIG_FILE = "config.yaml"


def write_config(out_dir: str | Path, cfg: dict) -> Path | None:
    """``config.yaml``, the run's resolved settings (what :func:`load_policy` rebuilds the task
    from), atomically, unless the folder has one (the app writes it before the run starts)."""
    from omegaconf import OmegaConf

    path = Path(out_dir) / CONFIG_FILE
    if path.is_file():
        return path
    try:
        text = OmegaConf.to_yaml(OmegaConf.create(cfg))
    except Exception:  # a hand-built config holding objects YAML cannot hold: no config.yaml
        return None
    return atomic_write_bytes(path, text.encode())


# the experiments whose runs are a policy: a trained map of a self-improvement experiment
POLICY_EXPERIMENTS = ("arm_reach", "point_particle", "self_improve")


def _experiment_class(name: str):
    from .arm_reach import ArmReachExperiment
    from .point_particle import PointParticleExperiment
    from .self_improve import GenericExperiment

    return {"arm_reach": ArmReachExperiment, "point_particle": PointParticleExperiment,
            "self_improve": GenericExperiment}[name]


def rebuild_experiment(cfg: dict, where: str = "run"):
    """The run's experiment object as the run built it (settings checked by
    :func:`~protorch.experiments.check_config`, the task made by the experiment's own
    ``configure``), without its demonstrations or loop: what the policy needs of it."""
    from . import SettingsError, check_config

    name = cfg.get("name") if isinstance(cfg, dict) else None
    if name not in POLICY_EXPERIMENTS:
        raise ValueError(f"{where}: experiment {name!r} is not a self-improvement run with a policy "
                         f"(one of {', '.join(POLICY_EXPERIMENTS)})")
    try:
        kwargs = check_config(cfg)
    except SettingsError as exc:
        raise ValueError(f"{where}: its config.yaml is refused by this protorch ({exc}); an older format? "
                         "re-run it") from None
    cls = _experiment_class(name)
    accepted = set()
    for c in cls.__mro__:
        init = c.__dict__.get("__init__")
        if init is not None:
            accepted |= set(inspect.signature(init).parameters) - {"self", "settings", "args"}
    return cls(**{k: v for k, v in kwargs.items() if k in accepted})


def _moving_test_defaults(name: str) -> dict:
    """The moving test's own defaults (what the run used where its config left them out)."""
    if name == "arm_reach":
        from ..control.arm import run_arm_episodes

        fn = run_arm_episodes
    elif name == "point_particle":
        from ..control.particle import run_episodes as fn
    else:
        return {}
    return {k: p.default for k, p in inspect.signature(fn).parameters.items()
            if k in ("duration", "dt", "switch_margin") and p.default is not inspect.Parameter.empty}


def load_policy(run: str | Path, *, device=None, dtype=None, backend: str | None = None, warm_up: bool = True,
                **options):
    """A run folder as a :class:`~protorch.control.policy.Policy` (``protorch.load``): the map
    from ``checkpoint/``, the task, the ProMP's size, the motion's duration and the class choice's
    settings from the run's ``config.yaml`` through the experiment's own builder
    (:func:`rebuild_experiment`). A folder without ``config.yaml`` (a checkpoint written by
    :func:`protorch.save_model`, a loop baseline's folder) gives the map alone (``task=None``).
    ``device``, ``dtype`` (float64 by default), ``backend``: of the map (as
    :func:`protorch.data.checkpoint.load`; the policy's per-call path is float64 whatever the map's
    dtype). ``options`` override :class:`~protorch.control.policy.Policy`'s settings
    (``duration``, ``switch_margin``, ``decision_dt``, ``blend``)."""
    import torch
    from omegaconf import OmegaConf

    dtype = torch.float64 if dtype is None else dtype

    from ..control.policy import Policy
    from ..data.checkpoint import checkpoint_path, load

    p = Path(run)
    where = f"run={str(run)!r}"
    if not p.exists():
        raise FileNotFoundError(f"{where}: no such file or folder")
    config = p / CONFIG_FILE if p.is_dir() else None
    if config is None or not config.is_file():
        if not checkpoint_path(p).is_file():
            raise FileNotFoundError(f"{where} holds no checkpoint ({checkpoint_path(p)}) and no {CONFIG_FILE}: "
                                    "give a run folder of arm_reach, point_particle or self_improve")
        model = load(p, device=device, dtype=dtype, backend=backend)
        return Policy(model.promp, model.env_map, model.task_name, warm_up=warm_up, **options)
    try:
        cfg = OmegaConf.to_container(OmegaConf.load(config), resolve=True)
    except Exception as exc:
        raise ValueError(f"{where}: {config} is not a readable config ({exc})") from None
    exp = rebuild_experiment(cfg, where)
    if not checkpoint_path(p).is_file():
        raise FileNotFoundError(f"{where} holds no checkpoint ({checkpoint_path(p)}): the run did not get to "
                                "its loop; resume it")
    try:
        model = load(p, device=device, dtype=dtype, backend=backend, promp={"num_dof": exp.num_dof(), **exp.promp_cfg})
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    task = exp.task
    if model.task_name and getattr(task, "name", model.task_name) != model.task_name:
        raise ValueError(f"{where}: its checkpoint is of task {model.task_name!r} but config.yaml builds "
                         f"{getattr(task, 'name', '?')!r}")
    if hasattr(task, "to"):
        task.to(model.promp.basis.device)
    dyn = {**_moving_test_defaults(cfg["name"]), **dict(getattr(exp, "dyn_cfg", {}) or {})}
    settings = {"duration": float(dyn.get("duration", 1.0)), "switch_margin": float(dyn.get("switch_margin", 0.0)),
                "decision_dt": float(dyn.get("dt", 0.01)), **options}
    with torch.no_grad():
        return Policy(model.promp, model.env_map, model.task_name, task=task, experiment=cfg["name"],
                      warm_up=warm_up, **settings)
