"""A run's experiment rebuilt from its resolved ``config.yaml`` through the experiment's own
settings check and builder: what ``protorch.load`` needs of a run folder written without
``policy.json`` (:mod:`protorch.experiments.policy_record`)."""

from __future__ import annotations

from . import SettingsError, check_config
from . import policy_record as records
from .policy_record import POLICY_EXPERIMENTS

__all__ = ["POLICY_EXPERIMENTS", "policy_record", "rebuild_experiment"]


def _checked(cfg: dict, where: str) -> dict:
    name = cfg.get("name") if isinstance(cfg, dict) else None
    if name not in POLICY_EXPERIMENTS:
        raise ValueError(
            f"{where}: experiment {name!r} is not a self-improvement run with a policy "
            f"(one of {', '.join(POLICY_EXPERIMENTS)})"
        )
    try:
        return check_config(cfg)
    except SettingsError as exc:
        raise ValueError(
            f"{where}: its config.yaml is refused by this protorch ({exc}); an older format? "
            "re-run it"
        ) from None


def rebuild_experiment(cfg: dict, where: str = "run"):
    """The run's experiment object as the run built it (settings checked by
    :func:`~protorch.experiments.check_config`, the task made by the experiment's own
    ``configure``), without its demonstrations or loop: what the policy needs of it."""
    return records.build_experiment(cfg["name"], _checked(cfg, where))


def policy_record(cfg: dict, where: str = "run") -> dict:
    """The ``policy.json`` record of a run of the resolved config ``cfg``."""
    return records.policy_record(cfg["name"], _checked(cfg, where))
