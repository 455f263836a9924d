"""The 2-D window task of the paper's Fig. 4 (and of the RWPO paper): from a start, through the
centre of a window in a wall, to an end point, in the unit square (the authors' geometry)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .base import Task

__all__ = ["WindowTask"]


def _checked_index(index: int) -> int:
    if index not in (0, 1, 2):
        raise ValueError(f"index must be 0, 1 or 2, got {index!r}")
    return index


@dataclass
class WindowTask(Task):
    """Objectives on a trajectory ``(..., T, 2)``: distance of ``tau(0)`` to ``start``, minimum
    over ``t`` of the distance to the window ``centre``, distance of ``tau(T)`` to ``end``.

    The wall is the vertical line ``x = centre_x`` with an opening of ``window_width`` around the
    centre; ``success`` asks every objective to be within ``tol`` and the path to cross the wall
    inside the opening.
    """

    start: tuple[float, float] = (0.1, 0.1)
    centre: tuple[float, float] = (0.5, 0.5)
    end: tuple[float, float] = (0.9, 0.9)
    window_width: float = 0.1
    demo_bias: float = 0.1
    name: str = "window"
    objective_names: tuple[str, ...] = ("start", "window", "end")

    def _pt(self, p, ref: Tensor) -> Tensor:
        return torch.as_tensor(p, dtype=ref.dtype, device=ref.device)

    def costs(self, traj: Tensor) -> Tensor:
        """``traj (..., T, 2)`` -> ``(..., 3)``: start, window (min over t), end distances."""
        self._check(traj)
        return torch.stack([self._objective(traj, o) for o in range(3)], -1)  # (..., 3)

    def objective_cost(self, traj: Tensor, index: int) -> Tensor:
        """Objective ``index`` of :meth:`costs` alone, ``(...)``, the same numbers: for a caller
        that evaluates only the objective an update reads (PRO's per-objective steps,
        ``PRO.asked_objective``). Objectives 0 and 2 read only the first and last steps
        (:meth:`objective_steps`), so ``traj`` may hold just those two."""
        self._check(traj)
        return self._objective(traj, _checked_index(index))

    def objective_steps(self, index: int) -> tuple[int, ...] | None:
        """The time steps objective ``index`` reads (``None``: all)."""
        return None if _checked_index(index) == 1 else (0, -1)

    def _check(self, traj: Tensor) -> None:
        if traj.ndim < 2 or traj.shape[-1] != 2:
            raise ValueError(
                f"window task trajectories must be (..., T, 2), got shape {tuple(traj.shape)}"
            )

    def _objective(self, traj: Tensor, index: int) -> Tensor:
        if index == 1:
            return (traj - self._pt(self.centre, traj)).norm(dim=-1).amin(-1)  # (...)
        point, target = (
            (traj[..., 0, :], self.start) if index == 0 else (traj[..., -1, :], self.end)
        )
        return (point - self._pt(target, traj)).norm(dim=-1)  # (...)

    def crossing_height(self, traj: Tensor) -> Tensor:
        """``y`` where the path first crosses ``x = centre_x`` (NaN if it never does): ``(...)``."""
        x = traj[..., 0] - self.centre[0]  # (..., T)
        sign_change = (x[..., :-1] <= 0) & (x[..., 1:] > 0)  # (..., T-1)
        idx = sign_change.to(torch.int64).argmax(-1, keepdim=True)  # (..., 1)
        x0, x1 = x.gather(-1, idx), x[..., 1:].gather(-1, idx)
        y0, y1 = traj[..., :-1, 1].gather(-1, idx), traj[..., 1:, 1].gather(-1, idx)
        y = (y0 + (y1 - y0) * (-x0) / (x1 - x0).clamp_min(1e-12))[..., 0]
        return torch.where(sign_change.any(-1), y, torch.full_like(y, float("nan")))

    def success(self, traj: Tensor, tol: float = 0.1) -> Tensor:
        ok = (self.costs(traj) <= tol).all(-1)
        y = self.crossing_height(traj)
        inside = (y - self.centre[1]).abs() <= self.window_width / 2
        return ok & inside

    def demonstrations(
        self, num: int = 5, *, generator: torch.Generator | None = None, dtype=torch.float64
    ) -> list[Tensor]:
        """Imperfect, human-like demonstrations of varying lengths: ``num`` tensors ``(T_i, 2)``.

        Each is a smooth path through jittered start, window and end points (start and end off by
        about 0.06, the window passed ``demo_bias`` above its centre, as an operator cutting the
        corner would), with a random bulge, sampled at 80 to 160 steps with small hand tremor.
        """
        if num < 1:
            raise ValueError(f"num must be >= 1, got {num}")
        g = generator
        demos = []
        start, centre, end = (
            torch.tensor(p, dtype=dtype) for p in (self.start, self.centre, self.end)
        )
        for _ in range(num):
            length = int(torch.randint(80, 161, (1,), generator=g))
            via = torch.stack(
                [
                    start + 0.06 * torch.randn(2, generator=g, dtype=dtype),
                    centre
                    + torch.tensor([0.0, 1.0], dtype=dtype)
                    * (self.demo_bias + 0.04 * torch.randn(1, generator=g, dtype=dtype)),
                    end + 0.06 * torch.randn(2, generator=g, dtype=dtype),
                ]
            )  # (3, 2)
            s = torch.linspace(0, 1, length, dtype=dtype)[:, None]  # (T, 1)
            # quadratic through the three via points at s = 0, 0.5, 1, plus a random bulge
            l0, l1, l2 = 2 * (s - 0.5) * (s - 1), -4 * s * (s - 1), 2 * s * (s - 0.5)
            path = l0 * via[0] + l1 * via[1] + l2 * via[2]  # (T, 2)
            bulge = (
                0.08 * torch.randn(1, 2, generator=g, dtype=dtype) * torch.sin(torch.pi * s) ** 2
            )
            bulge = bulge * (2 * s - 1).sign().neg()  # pushes the halves apart, keeps the middle
            path = path + bulge + 0.003 * torch.randn(length, 2, generator=g, dtype=dtype)
            demos.append(path)
        return demos
