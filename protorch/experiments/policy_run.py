"""A run's policy record (``policy.json``, what ``protorch.load`` builds the policy from without
importing the experiments) and a run's experiment rebuilt from its resolved ``config.yaml``
through the experiment's own settings check and builder (for run folders written before
``policy.json``, and for the record itself)."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

from ..data.files import atomic_write_bytes
from ..policy.load import POLICY_FILE, RECORD_FORMAT
from . import SettingsError, check_config
from .registry import REGISTRY

__all__ = ["POLICY_EXPERIMENTS", "policy_record", "rebuild_experiment", "write_policy_record"]

# the experiments whose runs are a policy: a trained map of a self-improvement experiment
POLICY_EXPERIMENTS = tuple(name for name, e in REGISTRY.items() if e.policy is not None)


def _rebuild(cfg: dict, where: str):
    """``(the registry's experiment class, the experiment object, the checked settings)``."""
    name = cfg.get("name") if isinstance(cfg, dict) else None
    if name not in POLICY_EXPERIMENTS:
        raise ValueError(
            f"{where}: experiment {name!r} is not a self-improvement run with a policy "
            f"(one of {', '.join(POLICY_EXPERIMENTS)})"
        )
    try:
        kwargs = check_config(cfg)
    except SettingsError as exc:
        raise ValueError(
            f"{where}: its config.yaml is refused by this protorch ({exc}); an older format? "
            "re-run it"
        ) from None
    exp = REGISTRY[name]
    cls = exp.policy
    assert cls is not None  # (POLICY_EXPERIMENTS)
    accepted = set()
    for c in cls.__mro__:
        init = c.__dict__.get("__init__")
        if init is not None:
            accepted |= set(inspect.signature(init).parameters) - {"self", "settings", "args"}
    return exp, cls(**{k: v for k, v in kwargs.items() if k in accepted}), kwargs


def rebuild_experiment(cfg: dict, where: str = "run"):
    """The run's experiment object as the run built it (settings checked by
    :func:`~protorch.experiments.check_config`, the task made by the experiment's own
    ``configure``), without its demonstrations or loop: what the policy needs of it."""
    return _rebuild(cfg, where)[1]


def policy_record(cfg: dict, where: str = "run") -> dict:
    """What :func:`protorch.load` needs of a run of ``cfg`` (plain JSON): the experiment's name,
    the task's class and constructor keyword arguments (the arm's robot settings among them), the
    ProMP's size and the policy's settings (the motion's duration, the class choice's)."""
    exp, obj, kwargs = _rebuild(cfg, where)
    task = obj.task
    return {
        "format": RECORD_FORMAT,
        "experiment": exp.name,
        "task": {
            "class": f"{type(task).__module__}.{type(task).__qualname__}",
            "kwargs": exp.task_kwargs(kwargs),
        },
        "promp": {"num_dof": int(obj.num_dof()), **obj.promp_cfg},
        "policy": exp.policy_settings(getattr(obj, "dyn_cfg", None)),
    }


def write_policy_record(out_dir: Path, cfg: dict) -> Path | None:
    """Write ``out_dir/policy.json`` (atomically) for a run of an experiment whose runs are a
    policy; ``None`` (nothing written) for the others."""
    if cfg.get("name") not in POLICY_EXPERIMENTS:
        return None
    text = json.dumps(policy_record(cfg, f"run={str(out_dir)!r}"), indent=1) + "\n"
    return atomic_write_bytes(Path(out_dir) / POLICY_FILE, text.encode())
