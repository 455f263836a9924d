"""A task is a small class holding an experiment's geometry and its objectives."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Protocol, runtime_checkable

import torch
from torch import Tensor

from ..errors import ProtorchError

__all__ = [
    "Task",
    "SelfImprovementTask",
    "check_task_protocol",
    "check_task_outputs",
    "TaskContractError",
    "PROTOCOL_MEMBERS",
]


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
    def costs(self, *args: Any, **kwargs: Any) -> Tensor:
        """Objective values of a batch of inputs (a subclass names them: ``x``, or ``traj`` and
        ``env``); the last output axis holds the ``O`` objectives."""

    def success(self, *args: Any, **kwargs: Any) -> Tensor:  # pragma: no cover - optional
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
        """Objectives ``(..., O)`` (each >= 0, lower is better) of ``traj (..., T, D)`` in ``env
        (..., E)``."""

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        """Whether ``traj (..., T, D)`` solves the task in ``env (..., E)``: ``(...)`` bool."""

    def demonstrations(
        self, num_envs: int, per_env: int, generator: torch.Generator
    ) -> tuple[list, Tensor]:
        """``(list of (T_i, D) trajectories, (n, E) environment of each)``."""


class TaskContractError(ProtorchError, TypeError, ValueError):
    """A task that does not follow :class:`SelfImprovementTask`: a member missing, or ``costs`` /
    ``success`` returning what the protocol does not allow. Its message is one line naming the
    member, what it returned and what it must return. (A ``TypeError`` and a ``ValueError``, so
    callers catching either keep working.)"""


PROTOCOL_MEMBERS = (
    "name",
    "num_dof",
    "env_dim",
    "sample_envs",
    "costs",
    "success",
    "demonstrations",
)


def check_task_protocol(task, *, demonstrations: bool = True) -> None:
    """Raise :class:`TaskContractError` (a ``TypeError``) naming every member of
    :class:`SelfImprovementTask` that ``task`` lacks
    (``demonstrations`` may be left out when they come from files)."""
    needed = [m for m in PROTOCOL_MEMBERS if demonstrations or m != "demonstrations"]
    missing = [m for m in needed if not hasattr(task, m)]
    if missing:
        raise TaskContractError(
            f"task {type(task).__module__}.{type(task).__qualname__} lacks {', '.join(missing)} "
            f"(a self-improvement task needs {', '.join(needed)}; see "
            "protorch.tasks.SelfImprovementTask)"
        )
    for m in ("num_dof", "env_dim"):
        v = getattr(task, m)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise TaskContractError(f"task.{m} must be an int >= 1, got {v!r}")


def _dims(*dims) -> str:
    return "(" + ", ".join(map(str, dims)) + ("," if len(dims) == 1 else "") + ")"


def _shape(x) -> str:
    return _dims(*x.shape)


def _returned(
    task, method: str, traj: Tensor, env: Tensor, must: str
) -> tuple[str, Tensor, tuple, str]:
    """``(where, what task.method(traj, env) returned, the batch shape, what it must return)``; a
    raise or a return that is no tensor is refused here. ``must`` is formatted with ``{lead}``."""
    name = f"{type(task).__module__}.{type(task).__qualname__}"
    where = f"task {name}: {method}(traj {_shape(traj)}, env {_shape(env)})"
    lead = tuple(traj.shape[:-2])
    must = must.format(lead=_dims(*lead), lead_o=_dims(*lead, "O"))
    try:
        out = getattr(task, method)(traj, env)
    except Exception as exc:  # the task's own error, on one line, with where it happened
        text = " ".join(str(exc).split())
        raise TaskContractError(f"{where} raised {type(exc).__name__}: {text}") from exc
    if not isinstance(out, Tensor):
        raise TaskContractError(f"{where} returned a {type(out).__name__}; {must}")
    return where, out, lead, must


def _check_costs(task, traj: Tensor, env: Tensor) -> int:
    where, c, lead, must = _returned(
        task, "costs", traj, env, "it must return {lead_o} with O >= 1 (one column per objective)"
    )
    if c.ndim != len(lead) + 1 or tuple(c.shape[:-1]) != lead or c.shape[-1] < 1:
        raise TaskContractError(f"{where} returned shape {_shape(c)}; {must}")
    if not c.is_floating_point():
        raise TaskContractError(
            f"{where} returned dtype {c.dtype}; it must return floating-point costs"
        )
    bad = ~torch.isfinite(c)
    if bool(bad.any()):
        i = tuple(int(v) for v in torch.nonzero(bad)[0])
        raise TaskContractError(
            f"{where} returned {float(c[i])} at index {i}; every cost must be finite and >= 0"
        )
    if bool((c < 0).any()):
        i = tuple(int(v) for v in torch.nonzero(c < 0)[0])
        raise TaskContractError(
            f"{where} returned {float(c[i]):.6g} at index {i}; every cost must be >= 0 "
            "(lower is better, 0 = met)"
        )
    return int(c.shape[-1])


def _check_success(task, traj: Tensor, env: Tensor) -> None:
    where, ok, lead, must = _returned(
        task, "success", traj, env, "it must return {lead} bool (one flag per trajectory)"
    )
    if tuple(ok.shape) != lead or ok.dtype != torch.bool:
        raise TaskContractError(f"{where} returned shape {_shape(ok)}, dtype {ok.dtype}; {must}")


def check_task_outputs(
    task, traj: Tensor, env: Tensor, *, samples: int = 2, dtype: torch.dtype | None = None
) -> int:
    """Call ``task.costs`` and ``task.success`` once on trajectories ``traj (n, T, D)`` in their
    environments ``env (n, E)`` (the demonstrations, before any work) and once in the batched form
    the self-improvement loop uses (``samples`` trajectories per environment, ``traj (n, S, T, D)``
    with ``env (n, 1, E)``, in ``dtype``, e.g. the loop's evaluation dtype). Raises
    :class:`TaskContractError` (one line: the method, the shapes given, what it returned and what
    it must return) where the costs are not ``(..., O)``, ``O >= 1``, finite and >= 0, or success
    is not ``(...)`` bool, or either raises. Returns ``O``."""
    num_objectives = _check_costs(task, traj, env)
    _check_success(task, traj, env)
    dtype = dtype or traj.dtype
    batch, benv = (
        traj[:, None].expand(-1, samples, -1, -1).to(dtype),
        env[:, None].to(dtype),
    )  # (n, S, T, D), (n, 1, E)
    if _check_costs(task, batch, benv) != num_objectives:
        raise TaskContractError(
            f"task {type(task).__qualname__}: costs returned {num_objectives} objectives for "
            f"traj {_shape(traj)} but a different number for traj {_shape(batch)}"
        )
    _check_success(task, batch, benv)
    return num_objectives
