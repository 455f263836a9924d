"""Reward-weighted regression over the weight Gaussian: PRO with every relevance equal to 1."""

from __future__ import annotations

from typing import Generator

import torch
from torch import Tensor

from .base import BaseOptimizer
from .functional import pro_update

__all__ = ["RWR"]


class RWR(BaseOptimizer):
    """RWR (Peters and Schaal 2007) on a diagonal Gaussian: each iteration asks ``num_samples``
    weights from ``N(mean, diag(var))``, scores them with ``exp(-beta * sum_o c_o * cost_o)``
    and refits the Gaussian by weighted maximum likelihood: ``mean' = sum R w / sum R`` and
    ``var' = sum R (w - mean')^2 / sum R``, around the *new* mean, the textbook RWR update
    (``center="old"`` gives PRO's Eq. 5 with every relevance 1 instead).
    ``objective_weights`` (``(O,)``, default all ones) combines the objectives into one cost.

    Example: the first ask of a batch of ``B = 2`` problems, ``N = 3`` weights; costs
    ``(B, S, O)``

    >>> opt = RWR(torch.zeros(2, 3), torch.ones(2, 3), beta=10.0, num_samples=20)
    >>> w = opt.ask()  # (B, S, N): ``num_samples`` from ``N(mean, diag(var))``
    >>> w.shape
    torch.Size([2, 20, 3])
    >>> opt.tell((w - 1).pow(2).sum(-1, keepdim=True))  # (B, S, 1)
    """

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor,
        objective_weights=None,
        center: str = "new",
        **kwargs,
    ):
        super().__init__(mean, var, beta=beta, **kwargs)
        if center not in ("new", "old"):
            raise ValueError(f"center must be 'new' or 'old', got {center!r}")
        self.center = center
        self._set_objective_weights(objective_weights)

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        w = self._sample(self.var, self.num_samples)  # (B, S, N)
        costs = yield w  # (B, S, O)
        self._record_cost(slice(None), costs)
        rows = self._active_rows()  # the update of the problems still moving (all: no gather)
        pick = (lambda x: x) if rows is None else (lambda x: x[rows])
        mean = pick(self.mean)  # (a, N)
        total = self._total_cost(pick(costs))  # (a, S)
        new_mean, new_var = pro_update(
            mean,
            pick(self.var),
            pick(w),
            total,
            torch.ones_like(mean),
            pick(self.beta),
            validate=False,
        )
        if (
            self.center == "new"
        ):  # weighted ML: E_R[(w - mean')^2] = E_R[(w - mean)^2] - (mean' - mean)^2
            new_var = new_var - (new_mean - mean) ** 2
        self._apply_rows(rows, new_mean, new_var)
