"""The experiments, each one class in one registry (:data:`REGISTRY`, keyed by the experiment's
name): what the app's settings check (:func:`protorch.experiments.check_config`), the run summary
(:mod:`protorch.experiments.summary`), ``protorch.load`` (through the run's ``policy.json``), the
viewer, the teach page and the policy settings need of an experiment, so that no module compares
experiment names.

An experiment class names its ``run`` function, the task class it runs (``None``: any task,
``task._target_``), its settings schemas (:mod:`protorch.experiments.settings`), its summary rows
(:class:`~protorch.experiments.headlines.Headline`), how it takes the optimizer group, and, for a
self-improvement experiment whose run is a policy, its experiment object (``policy``), the moving
test whose settings the policy keeps (``moving_test``) and the viewer's scene kind (``scene``).

>>> from protorch.experiments.registry import REGISTRY
>>> REGISTRY["point_particle"].task.__name__, REGISTRY["point_particle"].scene
('PointParticleTask', 'particle')
"""

from __future__ import annotations

from dataclasses import fields
from typing import Callable, ClassVar

from ..control.arm import run_arm_episodes
from ..control.particle import run_episodes
from ..policy.settings import policy_settings
from ..tasks import (
    ArmReachTask,
    BeamWindowTask,
    LineToy,
    PointParticleTask,
    TeleopWindowTask,
    WindowTask,
)
from . import (
    arm_reach,
    beam_window,
    fig3_toy,
    fig4_window,
    point_particle,
    self_improve,
    teleop_window,
)
from . import headlines as rows
from .arm_physics import check_physics, skip_reason
from .settings import (
    ArmReachSettings,
    ArmReachTaskSettings,
    PointParticleSettings,
    PointParticleTaskSettings,
    SelfImproveSettings,
    SettingsError,
)

__all__ = ["Experiment", "REGISTRY", "experiment", "for_task"]


def _tuples(cfg: dict) -> dict:
    """Lists as tuples (a config's sequences as the task classes take them)."""
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items()}


class Experiment:
    """One experiment's hooks (class attributes and class methods; never instantiated)."""

    name: ClassVar[str]
    run: ClassVar[Callable[..., dict]]  # run(out_dir, **settings) -> metrics
    task: ClassVar[type | None] = None  # the task class it runs; None: any (task._target_)
    group_optimizer: ClassVar[bool] = False  # the optimizer group as it is, else per method
    settings_schema: ClassVar[type | None] = None  # settings.* (experiments/settings.py)
    task_schema: ClassVar[type | None] = None  # task.*
    headlines: ClassVar[list] = []  # the summary's rows (experiments/headlines.py)
    policy: ClassVar[type | None] = None  # the experiment object of a run that is a policy
    moving_test: ClassVar[Callable | None] = None  # whose defaults the policy's settings take
    velocity_command: ClassVar[bool] = False  # the policy rolls out the arm's velocity command
    scene: ClassVar[str | None] = None  # the viewer's scene kind; None: not shown

    @classmethod
    def check_settings(cls, cfg: dict, settings: dict) -> None:
        """Relations between settings the schemas cannot state (raise :class:`SettingsError`)."""

    @classmethod
    def take_robot(cls, robot, settings: dict, task_cfg: dict) -> None:
        """Check the ``robot`` group and put it into ``settings``; only the arm takes one."""
        if robot is not None:
            raise SettingsError(
                f"robot=...: experiment {cls.name!r} takes no robot (experiment=arm_reach does)"
            )

    @classmethod
    def task_kwargs(cls, settings: dict) -> dict:
        """The task constructor's keyword arguments from the run's settings (its ``task.*``
        settings but those that only shape the training, e.g. ``demo_envs``), as the experiment
        passes them."""
        task_cfg = dict(settings.get("task") or {})
        return _tuples({k: v for k, v in task_cfg.items() if k != "_target_"})

    @classmethod
    def policy_settings(cls, dynamic: dict | None, **options) -> dict:
        """:class:`~protorch.policy.Policy`'s settings from the run's moving test's settings."""
        return policy_settings(
            dynamic,
            moving_test=cls.moving_test,
            velocity_command=cls.velocity_command,
            **options,
        )


class Fig3Toy(Experiment):
    name, run, task = "fig3_toy", staticmethod(fig3_toy.run), LineToy
    headlines = rows.FIG3_TOY


class Fig4Window(Experiment):
    name, run, task = "fig4_window", staticmethod(fig4_window.run), WindowTask
    headlines = rows.FIG4_WINDOW


class BeamWindow(Experiment):
    name, run, task = "beam_window", staticmethod(beam_window.run), BeamWindowTask
    headlines = rows.BEAM_WINDOW


class TeleopWindow(Experiment):
    name, run, task = "teleop_window", staticmethod(teleop_window.run), TeleopWindowTask
    group_optimizer, headlines = True, rows.TELEOP_WINDOW


class PointParticle(Experiment):
    name, run, task = "point_particle", staticmethod(point_particle.run), PointParticleTask
    group_optimizer, headlines = True, rows.POINT_PARTICLE
    settings_schema, task_schema = PointParticleSettings, PointParticleTaskSettings
    policy, moving_test, scene = point_particle.PointParticleExperiment, run_episodes, "particle"

    @classmethod
    def task_kwargs(cls, settings: dict) -> dict:
        keys = ("objectives", "fixed_start", "infinite_wall")  # PointParticleExperiment.configure
        return _tuples({k: v for k, v in dict(settings.get("task") or {}).items() if k in keys})


class ArmReach(Experiment):
    name, run, task = "arm_reach", staticmethod(arm_reach.run), ArmReachTask
    group_optimizer, headlines = True, rows.ARM_REACH
    settings_schema, task_schema = ArmReachSettings, ArmReachTaskSettings
    policy, moving_test, scene = arm_reach.ArmReachExperiment, run_arm_episodes, "arm"
    velocity_command = True

    @classmethod
    def check_settings(cls, cfg: dict, settings: dict) -> None:
        """The physics settings' relations, and MuJoCo where ``physics.run=always``."""
        try:
            check_physics(settings.get("physics"), dict(settings.get("dynamic") or {}))
        except (ValueError, ImportError) as exc:
            raise SettingsError(
                f"settings.{exc}" if str(exc).startswith("physics.") else str(exc)
            ) from None
        if "urdf" in dict(cfg.get("task") or {}):
            raise SettingsError(
                "task.urdf is now robot.urdf: robot=custom robot.urdf=PATH robot.end_link=LINK "
                "robot.home=[...] (docs/your_own_robot.md)"
            )

    @classmethod
    def take_robot(cls, robot, settings: dict, task_cfg: dict) -> None:
        """The robot and the workspace, before any work (:func:`protorch.robots.load_robot`)."""
        try:
            phys = check_physics(settings.get("physics"), dict(settings.get("dynamic") or {}))
            task_cfg = {k: v for k, v in task_cfg.items() if k != "_target_"}
            arm_reach.check_robot(robot, task_cfg, skip_reason(phys) is None)
        except (ValueError, ImportError) as exc:
            raise SettingsError(" ".join(str(exc).split())) from None
        if robot is not None:
            settings["robot"] = dict(robot)

    @classmethod
    def task_kwargs(cls, settings: dict) -> dict:
        """Every setting :class:`ArmReachTask` takes (its collision model and can objective among
        them), as :meth:`ArmReachExperiment.configure` passes them, and the ``robot`` group
        (``None``: the Panda)."""
        keys = {f.name for f in fields(ArmReachTask) if f.init and f.name not in ("robot", "name")}
        task_cfg = dict(settings.get("task") or {})
        robot = settings.get("robot")
        return {
            **{k: v for k, v in task_cfg.items() if k in keys},
            "robot": None if robot is None else dict(robot),
        }


class SelfImprove(Experiment):
    name, run = "self_improve", staticmethod(self_improve.run)
    group_optimizer, headlines = True, rows.SELF_IMPROVE
    settings_schema, policy = SelfImproveSettings, self_improve.GenericExperiment

    @classmethod
    def task_kwargs(cls, settings: dict) -> dict:
        own = self_improve._PIPELINE_KEYS  # build_task's: the pipeline's, not the constructor's
        task_cfg = dict(settings.get("task") or {})
        return _tuples({k: v for k, v in task_cfg.items() if k != "_target_" and k not in own})


REGISTRY: dict[str, type[Experiment]] = {
    e.name: e
    for e in (Fig3Toy, Fig4Window, PointParticle, BeamWindow, ArmReach, SelfImprove, TeleopWindow)
}


def experiment(name) -> type[Experiment]:
    """The registered experiment ``name``; :class:`SettingsError` naming the choices if none."""
    if name not in REGISTRY:
        raise SettingsError(f"experiment={name!r} must be one of {', '.join(sorted(REGISTRY))}")
    return REGISTRY[name]


def for_task(task_name) -> type[Experiment] | None:
    """The experiment whose runs are a policy of the task named ``task_name`` (a checkpoint's
    ``task_name``), or ``None``."""
    found = [e for e in REGISTRY.values() if getattr(e.task, "name", None) == task_name]
    return found[0] if found and found[0].policy is not None else None
