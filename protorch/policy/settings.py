"""A trained run's class-choice settings for :class:`~protorch.policy.policy.Policy`, from the
run's moving test's settings (``settings.dynamic`` of its ``config.yaml``): what
:func:`protorch.load` and the viewer's play button (:class:`~protorch.view.live.ArmPlayer`) build
their policy with."""

from __future__ import annotations

import inspect
from typing import Callable

__all__ = ["moving_test_defaults", "policy_settings"]


def moving_test_defaults(moving_test: Callable | None) -> dict:
    """The moving test's own defaults (what the run used where its config left them out):
    ``moving_test`` is the test's function (e.g. :func:`protorch.control.arm.run_arm_episodes`,
    the experiment's ``moving_test`` in :mod:`protorch.experiments.registry`), ``None``: none."""
    if moving_test is None:
        return {}
    fn = moving_test
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


def policy_settings(
    dynamic: dict | None,
    *,
    moving_test: Callable | None = None,
    velocity_command: bool = False,
    **options,
) -> dict:
    """:class:`~protorch.policy.policy.Policy`'s settings from a run's moving test's settings
    ``dynamic`` (the run's ``settings.dynamic``; the test's own defaults, those of the function
    ``moving_test``, where it leaves one out): the motion's duration, the decision interval, the
    switch margin, the plan check and, with ``velocity_command`` (the arm), the velocity command
    the check rolls out and the check's hysteresis. ``options`` override them."""
    dyn = {**moving_test_defaults(moving_test), **dict(dynamic or {})}
    settings = {
        "duration": float(dyn.get("duration", 1.0)),
        "switch_margin": float(dyn.get("switch_margin", 0.0)),
        "decision_dt": float(dyn.get("dt", 0.01)),
        "check": bool(dyn.get("check", False)),
        **options,
    }
    if velocity_command:  # the velocity command the check rolls out, and the check's hysteresis
        settings = {
            "kp": float(dyn.get("kp", 10.0)),
            "max_acceleration": dyn.get("max_acceleration"),
            "switch_clearance": float(dyn.get("switch_clearance", 0.0)),
            **settings,
        }
    return settings
