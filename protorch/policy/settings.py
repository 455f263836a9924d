"""A trained run's class-choice settings for :class:`~protorch.policy.policy.Policy`, from the
run's moving test's settings (``settings.dynamic`` of its ``config.yaml``): what
:func:`protorch.load` and the viewer's play button (:class:`~protorch.view.live.ArmPlayer`) build
their policy with."""

from __future__ import annotations

import inspect

from ..control.arm import run_arm_episodes
from ..control.particle import run_episodes

__all__ = ["moving_test_defaults", "policy_settings"]


def moving_test_defaults(name: str) -> dict:
    """The moving test's own defaults (what the run used where its config left them out)."""
    if name == "arm_reach":
        fn = run_arm_episodes
    elif name == "point_particle":
        fn = run_episodes
    else:
        return {}
    return {
        k: p.default
        for k, p in inspect.signature(fn).parameters.items()
        if k
        in (
            "duration",
            "dt",
            "switch_margin",
            "check",
            "kp",
            "max_acceleration",
            "switch_clearance",
        )
        and p.default is not inspect.Parameter.empty
    }


def policy_settings(name: str, dynamic: dict | None, **options) -> dict:
    """:class:`~protorch.policy.policy.Policy`'s settings for a run of experiment ``name`` from
    its moving test's settings ``dynamic`` (the run's ``settings.dynamic``; the test's own
    defaults where it leaves one out): the motion's duration, the decision interval, the switch
    margin, the plan check and, for the arm, the velocity command it rolls out and the check's
    hysteresis. ``options`` override them."""
    dyn = {**moving_test_defaults(name), **dict(dynamic or {})}
    settings = {
        "duration": float(dyn.get("duration", 1.0)),
        "switch_margin": float(dyn.get("switch_margin", 0.0)),
        "decision_dt": float(dyn.get("dt", 0.01)),
        "check": bool(dyn.get("check", False)),
        **options,
    }
    if name == "arm_reach":  # the velocity command the check rolls out, and the check's hysteresis
        settings = {
            "kp": float(dyn.get("kp", 10.0)),
            "max_acceleration": dyn.get("max_acceleration"),
            "switch_clearance": float(dyn.get("switch_clearance", 0.0)),
            **settings,
        }
    return settings
