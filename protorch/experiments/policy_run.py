"""A run folder as a policy (``protorch.load``): the run's experiment rebuilt from its resolved
``config.yaml`` through the experiment's own settings check and builder, the map from its
checkpoint, the class choice's settings from the moving test's."""

from __future__ import annotations

import inspect
from pathlib import Path

import torch
from omegaconf import OmegaConf

from ..control.policy import Policy
from ..control.policy_settings import policy_settings
from ..data.checkpoint import checkpoint_path, load
from . import SettingsError, check_config
from .arm_reach import ArmReachExperiment
from .point_particle import PointParticleExperiment
from .run_folder import CONFIG_FILE
from .self_improve import GenericExperiment

__all__ = ["POLICY_EXPERIMENTS", "rebuild_experiment", "load_policy"]

# the experiments whose runs are a policy: a trained map of a self-improvement experiment
POLICY_EXPERIMENTS = ("arm_reach", "point_particle", "self_improve")


def _experiment_class(name: str):
    return {"arm_reach": ArmReachExperiment, "point_particle": PointParticleExperiment,
            "self_improve": GenericExperiment}[name]


def rebuild_experiment(cfg: dict, where: str = "run"):
    """The run's experiment object as the run built it (settings checked by
    :func:`~protorch.experiments.check_config`, the task made by the experiment's own
    ``configure``), without its demonstrations or loop: what the policy needs of it."""
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
    (``duration``, ``switch_margin``, ``decision_dt``, ``blend``, ``check``, ``kp``, ``max_acceleration``,
    ``switch_clearance``)."""
    dtype = torch.float64 if dtype is None else dtype

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
    settings = policy_settings(cfg["name"], getattr(exp, "dyn_cfg", None), **options)
    with torch.no_grad():
        return Policy(model.promp, model.env_map, model.task_name, task=task, experiment=cfg["name"],
                      warm_up=warm_up, **settings)
