"""Experiment tasks: small classes with their geometry, objectives and success checks."""

from ..data.demos import load_human_demos
from .arm_reach import ArmReachTask
from .base import Task
from .beam_window import BeamWindowTask, SimulatedOperator
from .point_particle import PointParticleTask, signed_distance_to_wall, wall_collision
from .toy import LineToy
from .window import WindowTask

TASKS = {
    "line_toy": LineToy, "window": WindowTask, "point_particle": PointParticleTask, "beam_window": BeamWindowTask,
    "arm_reach": ArmReachTask,
}

__all__ = [
    "Task", "LineToy", "WindowTask", "PointParticleTask", "load_human_demos",
    "signed_distance_to_wall", "wall_collision", "TASKS", "BeamWindowTask", "SimulatedOperator", "ArmReachTask",
]
