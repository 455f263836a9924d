"""Experiment tasks: small classes with their geometry, objectives and success checks.

:data:`TASKS` maps a name to a class; :func:`task_class` resolves a name or a dotted path
(``my_module.MyTask``, any importable class) and :func:`make_task` builds one.
"""

import importlib

from ..data.demos import load_human_demos
from .arm import ArmReachTask
from .base import (
    PROTOCOL_MEMBERS,
    SelfImprovementTask,
    Task,
    TaskContractError,
    check_task_outputs,
    check_task_protocol,
)
from .beam_window import BeamWindowTask, SimulatedOperator
from .point_particle import PointParticleTask, signed_distance_to_wall, wall_collision
from .teleop_window import TeleopWindowTask
from .toy import LineToy
from .window import WindowTask

# name -> class, by each task class's own ``name``
TASKS: dict[str, type] = {
    cls.name: cls
    for cls in (
        LineToy,
        WindowTask,
        PointParticleTask,
        BeamWindowTask,
        ArmReachTask,
        TeleopWindowTask,
    )
}

__all__ = [
    "Task",
    "SelfImprovementTask",
    "check_task_protocol",
    "check_task_outputs",
    "TaskContractError",
    "PROTOCOL_MEMBERS",
    "task_class",
    "make_task",
    "LineToy",
    "WindowTask",
    "PointParticleTask",
    "load_human_demos",
    "signed_distance_to_wall",
    "wall_collision",
    "TASKS",
    "BeamWindowTask",
    "SimulatedOperator",
    "ArmReachTask",
    "TeleopWindowTask",
]


def task_class(target: str) -> type:
    """The task class named ``target``: a key of :data:`TASKS` or a dotted path ``module.Class``."""
    if target in TASKS:
        return TASKS[target]
    module, _, attr = str(target).rpartition(".")
    if not module:
        raise ValueError(
            f"task {target!r}: give a registered name ({', '.join(sorted(TASKS))}) or a dotted "
            "path "
            "module.Class"
        )
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise ValueError(
            f"task._target_={target!r}: cannot import {module!r} ({exc}); is it on PYTHONPATH?"
        ) from None
    if not isinstance(getattr(mod, attr, None), type):
        raise ValueError(f"task._target_={target!r}: module {module!r} has no class {attr!r}")
    return getattr(mod, attr)


def make_task(target: str, **kwargs):
    """``task_class(target)(**kwargs)``."""
    return task_class(target)(**kwargs)
