"""What a demonstration folder holds (:class:`DemoFormat`) and what reading one gives
(:class:`DemoFolder`), for both formats: :mod:`protorch.data.demos` (``trajK.out`` / ``envK.out``)
and :mod:`protorch.data.recordings` (timestamped ``*.csv``). Imports nothing of protorch."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from torch import Tensor

__all__ = ["DemoFolder", "DemoFormat"]


@dataclass(frozen=True)
class DemoFormat:
    """What one task's files hold: the trajectory's column names, the environment's names, and
    optional bounds ``(lo, hi)`` per column / per environment value with the bound's name
    (``"the workspace"``, ``"the joint limits"``) for the error messages."""

    columns: tuple[str, ...]
    env_names: tuple[str, ...]
    column_bounds: tuple[tuple[float, float], ...] | None = None
    env_bounds: tuple[tuple[float, float], ...] | None = None
    column_bound_name: str = "its bounds"
    env_bound_name: str = "its bounds"

    def __post_init__(self) -> None:
        for bounds, names, what in (
            (self.column_bounds, self.columns, "column_bounds"),
            (self.env_bounds, self.env_names, "env_bounds"),
        ):
            if bounds is not None and len(bounds) != len(names):
                raise ValueError(
                    f"{what} must hold one (lo, hi) per name {list(names)}, got {len(bounds)}"
                )


@dataclass
class DemoFolder:
    """A folder read by :func:`read_demos`: ``demos[i]`` ``(T_i, D)`` from ``files[i][0]``,
    ``envs[i]`` ``(E,)`` from ``files[i][1]``, ``indices[i]`` its ``K``, in increasing ``K``."""

    demos: list[Tensor]
    envs: Tensor  # (n, E)
    files: list[tuple[Path, Path]] = field(default_factory=list)
    indices: list[int] = field(default_factory=list)
    report: dict = field(
        default_factory=dict
    )  # a recordings folder's cleaning report (empty for trajK.out)
    stages: list = field(
        default_factory=list
    )  # a recordings folder's raw / trimmed / aligned arrays, per file
