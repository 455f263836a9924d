"""When an optimiser's problem has converged: the stop rules
:class:`~protorch.optim.base.BaseOptimizer` applies.

After every iteration the optimiser records, per problem and objective, the mean, the minimum
and the maximum cost of the samples that objective's update saw (``history["cost"]``,
``history["cost_min"]``, ``history["cost_max"]``, each ``(B, O)`` per iteration). A rule maps the
last ``window`` of those to a ``(B,)`` bool: the problems that converged now. Two rules:

* :class:`MeanWindow` (``convergence="mean"``, the default): every objective's *mean* sample cost
  stayed within ``tol`` (max - min over the window). This is protorch's own rule: it looks at
  the means, so a distribution whose samples still spread widely converges once its mean cost
  settles.
* :class:`AuthorsRule` (``convergence="authors"``): the rule of the authors' ``rwpo.optimize``
  (marcoewerton/avoid_moving_walls): *every sample's* cost of every objective stayed within
  ``tol`` over the window (max over samples and iterations minus min over them), plus optional
  quality thresholds on the last iteration: ``mean_at_most[o]`` bounds objective ``o``'s mean
  sample cost and ``best_at_most[o]`` its best (lowest) sample cost. The thresholds are
  task-specific; the experiments supply them (e.g. the point particle's start / end mean
  distance <= 0.005 and best clearance >= 0.1, i.e. a clearance cost ``1 - sd <= 0.9``).

An objective not recorded in an iteration (NaN) never counts as settled.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Protocol

import torch
from torch import Tensor

__all__ = ["ConvergenceRule", "MeanWindow", "AuthorsRule", "make_rule", "RULES"]

RULES = ("mean", "authors")


class ConvergenceRule(Protocol):
    """``rule(history) -> (B,) bool`` from the optimiser's per-iteration cost history."""

    @property
    def window(self) -> int:
        """Iterations the rule looks back over."""

    def __call__(self, history: Mapping[str, list[Tensor]]) -> Tensor: ...


def _spread(high: Tensor, low: Tensor) -> Tensor:
    """``(W, B, O)`` highs and lows -> ``(B, O)`` max - min over the window; NaN -> inf."""
    return (high.amax(0) - low.amin(0)).nan_to_num(nan=float("inf"))


def _check(tol: float, window: int) -> tuple[float, int]:
    tol = float(tol)
    if not tol >= 0 or isinstance(window, bool) or int(window) != window or int(window) < 1:
        raise ValueError(f"need tol >= 0 and window >= 1 (an int), got tol={tol}, window={window}")
    return tol, int(window)


@dataclass(frozen=True)
class MeanWindow:
    """Every objective's mean sample cost within ``tol`` over the last ``window`` iterations."""

    tol: float = 1e-3
    window: int = 5

    def __post_init__(self) -> None:
        _check(self.tol, self.window)

    def __call__(self, history: Mapping[str, list[Tensor]]) -> Tensor:
        cost = history["cost"]
        if self.tol <= 0 or len(cost) < self.window:
            return torch.zeros(
                cost[-1].shape[0] if cost else 0,
                dtype=torch.bool,
                device=cost[-1].device if cost else None,
            )
        recent = torch.stack(cost[-self.window :])  # (W, B, O)
        return (_spread(recent, recent) <= self.tol).all(-1)  # (B,)


@dataclass(frozen=True)
class AuthorsRule:
    """Every sample's cost of every objective within ``tol`` over the last ``window`` iterations,
    and the last iteration's ``mean_at_most`` / ``best_at_most`` thresholds (objective index ->
    bound) met."""

    tol: float = 1e-3
    window: int = 5
    mean_at_most: dict = field(default_factory=dict)
    best_at_most: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self.tol, self.window)
        for name in ("mean_at_most", "best_at_most"):
            for k, v in dict(getattr(self, name)).items():
                if isinstance(k, bool) or int(k) != k or int(k) < 0 or not float(v) == float(v):
                    raise ValueError(
                        f"{name} must map objective indices >= 0 to numbers, got {k!r}: {v!r}"
                    )

    def __call__(self, history: Mapping[str, list[Tensor]]) -> Tensor:
        cost = history["cost"]
        n = len(cost)
        if self.tol <= 0 or n < self.window:
            return torch.zeros(
                cost[-1].shape[0] if cost else 0,
                dtype=torch.bool,
                device=cost[-1].device if cost else None,
            )
        low = torch.stack(history["cost_min"][-self.window :])  # (W, B, O)
        high = torch.stack(history["cost_max"][-self.window :])  # (W, B, O)
        ok = (_spread(high, low) <= self.tol).all(-1)  # (B,)
        num_obj = cost[-1].shape[-1]
        for bounds, last in (
            (self.mean_at_most, cost[-1]),
            (self.best_at_most, history["cost_min"][-1]),
        ):
            for o, bound in bounds.items():
                if int(o) >= num_obj:
                    raise ValueError(
                        f"threshold on objective {o}, but the costs have {num_obj} objective(s)"
                    )
                ok &= last[:, int(o)].nan_to_num(nan=float("inf")) <= float(bound)  # (B,)
        return ok


def make_rule(convergence, *, tol: float, window: int) -> ConvergenceRule:
    """``"mean"`` / ``"authors"`` (no thresholds) with ``tol`` and ``window``, or a rule object
    (returned as it is; its own ``tol`` and ``window`` apply)."""
    if isinstance(convergence, str):
        if convergence == "mean":
            return MeanWindow(tol, window)
        if convergence == "authors":
            return AuthorsRule(tol, window)
        raise ValueError(
            f"convergence must be one of {list(RULES)} or a rule object, got {convergence!r}"
        )
    if not callable(convergence) or not hasattr(convergence, "window"):
        raise ValueError(
            f"convergence must be one of {list(RULES)} or a rule (callable with .window), "
            f"got {type(convergence).__name__}"
        )
    return convergence
