"""Experiment tasks: small classes with their geometry, objectives and success checks."""

from .base import Task
from .toy import LineToy
from .window import WindowTask

TASKS = {"line_toy": LineToy, "window": WindowTask}

__all__ = ["Task", "LineToy", "WindowTask", "TASKS"]
