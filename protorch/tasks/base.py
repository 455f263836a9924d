"""A task is a small class holding an experiment's geometry and its objectives."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Protocol, runtime_checkable

import torch
from torch import Tensor

__all__ = ["Task", "SelfImprovementTask", "check_task_protocol", "PROTOCOL_MEMBERS"]


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


@runtime_checkable
class SelfImprovementTask(Protocol):
    """What the self-improvement pipeline (``experiment=self_improve``) needs of a task.

    ``D = num_dof`` degrees of freedom, ``E = env_dim`` numbers per environment, ``O`` objectives.
    """

    name: str
    num_dof: int
    env_dim: int

    def sample_envs(self, n: int, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
        """``n`` random environments ``(n, E)``."""

    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """Objectives ``(..., O)`` (each >= 0, lower is better) of ``traj (..., T, D)`` in ``env (..., E)``."""

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        """Whether ``traj (..., T, D)`` solves the task in ``env (..., E)``: ``(...)`` bool."""

    def demonstrations(self, num_envs: int, per_env: int, generator: torch.Generator) -> tuple[list, Tensor]:
        """``(list of (T_i, D) trajectories, (n, E) environment of each)``."""


PROTOCOL_MEMBERS = ("name", "num_dof", "env_dim", "sample_envs", "costs", "success", "demonstrations")


def check_task_protocol(task, *, demonstrations: bool = True) -> None:
    """Raise ``TypeError`` naming every member of :class:`SelfImprovementTask` that ``task`` lacks
    (``demonstrations`` may be left out when they come from files)."""
    needed = [m for m in PROTOCOL_MEMBERS if demonstrations or m != "demonstrations"]
    missing = [m for m in needed if not hasattr(task, m)]
    if missing:
        raise TypeError(f"task {type(task).__module__}.{type(task).__qualname__} lacks {', '.join(missing)} "
                        f"(a self-improvement task needs {', '.join(needed)}; see protorch.tasks.SelfImprovementTask)")
    for m in ("num_dof", "env_dim"):
        v = getattr(task, m)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise TypeError(f"task.{m} must be an int >= 1, got {v!r}")
