"""The toy of the paper's Fig. 3: a 2-D Gaussian over ``(w1, w2)`` rewarded for closeness to the
line ``w2 = offset``, on which ``w1`` does not matter."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .base import Task

__all__ = ["LineToy"]


@dataclass
class LineToy(Task):
    """Cost ``d = |w2 - offset|``: the distance of the point ``w`` to a horizontal line."""

    offset: float = 2.0
    name: str = "line_toy"
    objective_names: tuple[str, ...] = ("line_distance",)

    def costs(self, w: Tensor) -> Tensor:
        """``w (..., 2)`` -> ``(..., 1)``."""
        if w.shape[-1] != 2:
            raise ValueError(f"the line toy takes 2-D points (..., 2), got shape {tuple(w.shape)}")
        return (w[..., 1:2] - self.offset).abs()

    def success(self, w: Tensor, tol: float = 1e-2) -> Tensor:
        return self.costs(w)[..., 0] <= tol

    def line(self, lo: float = -4.0, hi: float = 4.0) -> Tensor:
        """Two points of the line, for plotting: ``(2, 2)``."""
        return torch.tensor([[lo, self.offset], [hi, self.offset]])
