"""A run's experiment rebuilt from its resolved ``config.yaml`` through the experiment's own
settings check and builder: what ``protorch.load`` (:func:`protorch.policy.load.load_policy`)
needs of it."""

from __future__ import annotations

import inspect

from . import SettingsError, check_config
from .arm_reach import ArmReachExperiment
from .point_particle import PointParticleExperiment
from .self_improve import GenericExperiment

__all__ = ["POLICY_EXPERIMENTS", "rebuild_experiment"]

# the experiments whose runs are a policy: a trained map of a self-improvement experiment
POLICY_EXPERIMENTS = ("arm_reach", "point_particle", "self_improve")


def _experiment_class(name: str):
    return {
        "arm_reach": ArmReachExperiment,
        "point_particle": PointParticleExperiment,
        "self_improve": GenericExperiment,
    }[name]


def rebuild_experiment(cfg: dict, where: str = "run"):
    """The run's experiment object as the run built it (settings checked by
    :func:`~protorch.experiments.check_config`, the task made by the experiment's own
    ``configure``), without its demonstrations or loop: what the policy needs of it."""
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
    cls = _experiment_class(name)
    accepted = set()
    for c in cls.__mro__:
        init = c.__dict__.get("__init__")
        if init is not None:
            accepted |= set(inspect.signature(init).parameters) - {"self", "settings", "args"}
    return cls(**{k: v for k, v in kwargs.items() if k in accepted})
