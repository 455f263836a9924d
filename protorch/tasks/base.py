"""A task is a small class holding an experiment's geometry and its objectives."""

from __future__ import annotations

from abc import ABC, abstractmethod

from torch import Tensor

__all__ = ["Task"]


class Task(ABC):
    """Objectives ``costs(x (..., ...)) -> (..., O)``, each >= 0 and lower is better.

    ``objective_names`` has ``O`` entries; ``success`` says whether a trajectory solves the task.
    """

    name: str = "task"
    objective_names: tuple[str, ...] = ()

    @property
    def num_objectives(self) -> int:
        return len(self.objective_names)

    @abstractmethod
    def costs(self, x: Tensor) -> Tensor:
        """Objective values of a batch of inputs; the last output axis holds the ``O`` objectives."""

    def success(self, x: Tensor) -> Tensor:  # pragma: no cover - optional
        raise NotImplementedError(f"{type(self).__name__} defines no success criterion")
