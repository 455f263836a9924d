"""The ask / tell contract's record and check (:mod:`protorch.optim.base`): what an optimiser
returns (:class:`OptimizeResult`) and what ``tell`` accepts (:func:`check_costs`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..checks import all_finite, check_tensor

__all__ = ["OptimizeResult", "check_costs"]


@dataclass
class OptimizeResult:
    """What an optimiser returns: the final distribution and how it got there.

    ``history`` holds per-iteration tensors stacked on a leading iteration axis:
    ``cost (I, B, O)`` (mean cost of the samples each objective was updated with),
    ``mean (I, B, N)``, ``var (I, B, N)`` and, for relevance-based optimisers,
    ``relevance (I, B, O, N)``. ``rollouts (B,)`` counts the samples told while each problem was
    still active (the ones a caller evaluates; a converged problem's are never read). The batch
    dimension is dropped for unbatched optimisers.
    """

    mean: Tensor
    var: Tensor
    converged: Tensor
    iterations: int
    history: dict[str, Tensor] = field(default_factory=dict)
    relevance_seconds: list[float] = field(default_factory=list)
    rollouts: Tensor | None = None


def check_costs(
    costs,
    *,
    batched: bool,
    expect: tuple[int, int],
    dtype: torch.dtype,
    num_objectives: int | None,
    objective_weights: Tensor | None,
) -> Tensor:
    """What ``tell`` receives, as ``(B, S, O)`` in ``dtype``, or a ``ValueError`` naming what is
    wrong: ``(B, S) = expect`` (unbatched: ``(S, O)`` or ``(S,)``), ``O`` the objectives told before
    and the length of ``objective_weights``, no overflow in ``dtype``."""
    costs = check_tensor(costs, "costs")
    if not costs.is_floating_point():
        costs = costs.to(dtype)
    if not batched:
        costs = costs[None]
    if costs.ndim == 2:
        costs = costs[..., None]
    if costs.ndim != 3 or tuple(costs.shape[:2]) != expect:
        raise ValueError(
            f"costs must be (B, S, O) with (B, S) = {expect} (unbatched: (S, O)), got "
            f"{tuple(costs.shape)}"
        )
    if num_objectives is not None and costs.shape[-1] != num_objectives:
        raise ValueError(
            f"expected {num_objectives} objective(s), got costs of shape {tuple(costs.shape)}"
        )
    c = objective_weights
    if c is not None and tuple(c.shape) != (costs.shape[-1],):
        raise ValueError(
            f"objective_weights must be ({costs.shape[-1]},) to match the costs' "
            f"{costs.shape[-1]} objective(s), got shape {tuple(c.shape)}"
        )
    cast = costs.to(dtype)
    if cast is not costs and not all_finite(cast):
        raise ValueError(
            f"costs overflow the optimiser's {dtype} (largest |cost| "
            f"{float(costs.abs().max()):.3g}): rescale them or use dtype=torch.float64"
        )
    return cast
