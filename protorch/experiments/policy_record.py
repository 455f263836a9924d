"""A run's policy record, ``policy.json``: what ``protorch.load``
(:func:`protorch.policy.load.load_policy`) builds the policy from without importing the
experiments: the experiment's name, the task's class and constructor arguments (the arm's robot
settings among them), the ProMP's size and the policy's settings (the motion's duration, the class
choice's). Written atomically at the end of a run (:func:`protorch.experiments.run_experiment`)."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

from ..data.files import atomic_write_bytes
from ..policy.load import POLICY_FILE, RECORD_FORMAT
from .registry import REGISTRY

__all__ = ["POLICY_EXPERIMENTS", "build_experiment", "policy_record", "write_policy_record"]

# the experiments whose runs are a policy: a trained map of a self-improvement experiment
POLICY_EXPERIMENTS = tuple(name for name, e in REGISTRY.items() if e.policy is not None)


def build_experiment(name: str, kwargs: dict):
    """The experiment object of experiment ``name`` from its checked settings ``kwargs``
    (:func:`~protorch.experiments.check_config`'s), its task made by its own ``configure``,
    without its demonstrations or loop."""
    cls = REGISTRY[name].policy
    if cls is None:
        raise ValueError(f"experiment {name!r} is not a self-improvement run with a policy")
    accepted = set()
    for c in cls.__mro__:
        init = c.__dict__.get("__init__")
        if init is not None:
            accepted |= set(inspect.signature(init).parameters) - {"self", "settings", "args"}
    return cls(**{k: v for k, v in kwargs.items() if k in accepted})


def policy_record(name: str, kwargs: dict) -> dict:
    """The record (plain JSON) of a run of experiment ``name`` with checked settings ``kwargs``."""
    exp, obj = REGISTRY[name], build_experiment(name, kwargs)
    task = obj.task
    return {
        "format": RECORD_FORMAT,
        "experiment": name,
        "task": {
            "class": f"{type(task).__module__}.{type(task).__qualname__}",
            "kwargs": exp.task_kwargs(kwargs),
        },
        "promp": {"num_dof": int(obj.num_dof()), **obj.promp_cfg},
        "policy": exp.policy_settings(getattr(obj, "dyn_cfg", None)),
    }


def write_policy_record(out_dir: Path, name: str, kwargs: dict) -> Path | None:
    """Write ``out_dir/policy.json`` (atomically) for a run of an experiment whose runs are a
    policy; ``None`` (nothing written) for the others."""
    if name not in POLICY_EXPERIMENTS:
        return None
    text = json.dumps(policy_record(name, kwargs), indent=1) + "\n"
    return atomic_write_bytes(Path(out_dir) / POLICY_FILE, text.encode())
