"""PRO: Pearson-correlation-based Relevance weighted policy Optimization (Ewerton et al. 2019)."""

from __future__ import annotations

import time
from typing import Generator

import torch
from torch import Tensor

from ..checks import check_int, check_number
from .base import BaseOptimizer
from .functional import pearson_relevance, pro_update

__all__ = ["PRO"]


class PRO(BaseOptimizer):
    """PRO over ``B`` problems at once (see :class:`BaseOptimizer` for the contract).

    One iteration:

    1. every ``relevance_every`` iterations, ask ``relevance_samples`` weights drawn around the
       mean with the small uniform variance ``relevance_var`` and set
       ``f_o = pearson_relevance(w, costs)`` (Sec. III A);
    2. for each objective ``o`` in turn: ask ``num_samples`` weights from
       ``N(mean, diag(var * f_o))`` and apply :func:`pro_update` with objective ``o``'s costs
       (Eq. 4-6).

    Args:
        relevance_samples: samples for the correlation (the authors used 100 to 200).
        relevance_var: variance of those samples (the authors' code: 1e-5), in weight units.
        relevance_every: recompute the relevance every k iterations (1, the authors' choice, by
            default); 0 computes it once, at the first iteration.
        noise_floor: ``z`` of the relevance's noise floor: ``|rho| < z / sqrt(relevance_samples)``
            counts as 0 (see :func:`pearson_relevance`). Default 4, which keeps the irrelevant
            variance in the Fig. 3 toy; ``None`` is the paper's formula as written, under which
            sampling noise in rho slowly drains the variance of irrelevant weights.
        Other arguments: :class:`BaseOptimizer`.

    Example: the first ask of a batch of ``B = 2`` problems, ``N = 3`` weights; costs
    ``(B, S, O)``

    >>> opt = PRO(torch.zeros(2, 3), torch.ones(2, 3), beta=10.0, relevance_samples=50)
    >>> w = opt.ask()  # (B, S, N): the relevance samples first
    >>> w.shape
    torch.Size([2, 50, 3])
    >>> opt.tell((w - 1).pow(2).sum(-1, keepdim=True))  # (B, S, 1)
    """

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor,
        relevance_samples: int = 200,
        relevance_var: float = 1e-5,
        relevance_every: int = 1,
        noise_floor: float | None = 4.0,
        **kwargs,
    ) -> None:
        super().__init__(mean, var, beta=beta, **kwargs)
        self.relevance_samples = check_int(relevance_samples, "relevance_samples", 3)
        self.relevance_var = check_number(relevance_var, "relevance_var")  # finite, > 0
        self.relevance_every = check_int(relevance_every, "relevance_every", 0)
        if noise_floor is not None:
            noise_floor = check_number(noise_floor, "noise_floor", allow_zero=True)
        self.noise_floor = noise_floor
        self.relevance: Tensor | None = None  # (B, O, N)
        self.history["relevance"] = []

    @property
    def can_restart(self) -> bool:
        """A restarted problem needs its own relevance at its next iteration: only when every
        iteration computes it (``relevance_every=1``)."""
        return self.relevance_every == 1

    def _due(self) -> bool:
        if self.relevance is None:
            return True
        return self.relevance_every > 0 and self.iteration % self.relevance_every == 0

    def _relevance(self) -> Generator[Tensor, Tensor, Tensor]:
        """Ask the relevance samples and return ``f (B, O, N)`` (Sec. III A), computed for the
        problems still moving; a converged problem keeps its relevance (0 if it never had one)."""
        probe_var = torch.full_like(self.var, self.relevance_var)  # (B, N)
        w = self._sample(probe_var, self.relevance_samples)  # (B, S_rel, N)
        self.asked_objective = None  # the correlation reads every objective
        costs = yield w  # (B, S_rel, O)
        rows = self._active_rows()
        if rows is None:
            return pearson_relevance(w, costs, noise_floor=self.noise_floor)  # (B, O, N)
        rel = (
            self.relevance.clone()
            if self.relevance is not None
            else w.new_zeros(self.batch_size, costs.shape[-1], self.num_weights)
        )  # (B, O, N)
        moving = ~self.converged[rows]  # (r,) a converged problem keeps its relevance
        rel[rows[moving]] = pearson_relevance(w[rows], costs[rows], noise_floor=self.noise_floor)[
            moving
        ]
        return rel

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        if self._due():
            start = time.perf_counter()  # includes the caller's evaluation, as the paper's timing
            self.relevance = yield from self._relevance()  # (B, O, N)
            self.relevance_seconds.append(time.perf_counter() - start)
        relevance = self.relevance
        if relevance is None:
            raise RuntimeError("PRO's first iteration must compute the relevance")
        self.history["relevance"].append(relevance.clone())
        for o in range(self._objectives):
            f = relevance[:, o]  # (B, N)
            w = self._sample(self.var * f, self.num_samples)  # (B, S, N)
            self.asked_objective = o  # this update reads objective o only
            costs = yield w  # (B, S, O)
            self._record_cost(o, costs[..., o])
            rows = self._active_rows()  # the update of the problems still moving (all: no gather)
            pick = (lambda x: x) if rows is None else (lambda x: x[rows])
            new_mean, new_var = pro_update(
                pick(self.mean),
                pick(self.var),
                pick(w),
                pick(costs[..., o]),
                pick(f),
                pick(self.beta),
                validate=False,
            )
            self._apply_rows(rows, new_mean, new_var)
