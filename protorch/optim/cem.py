"""The cross-entropy method on a diagonal Gaussian, on the same ask / tell contract."""

from __future__ import annotations

import math
from typing import Generator

from torch import Tensor

from .base import BaseOptimizer

__all__ = ["CEM"]


class CEM(BaseOptimizer):
    """Cross-entropy method (Rubinstein 1999; as used for policy search, e.g. Szita and Lorincz
    2006) over ``B`` problems at once: each iteration asks ``num_samples`` weights from
    ``N(mean, diag(var))``, keeps the ``ceil(elite_frac * S)`` with the lowest total cost
    ``sum_o c_o * cost_o`` and refits the Gaussian to them by maximum likelihood:
    ``mean' = mean of the elites``, ``var' = their variance around mean'``, then
    ``mean <- (1 - smoothing) mean + smoothing mean'`` and the same for ``var``, plus
    ``extra_var`` (the noisy CEM of Szita and Lorincz, which keeps it from collapsing early).

    Rank-based: only the order of the costs matters, so there is no ``beta``.

    Args:
        elite_frac: fraction of the samples kept (default 0.1; at least 2 elites).
        smoothing: in ``(0, 1]``; 1 (default) is the plain refit.
        extra_var: ``>= 0`` added to every variance after the refit (default 0).
        objective_weights: ``(O,)``, default all ones: how objectives combine into one cost.
        Other arguments: :class:`BaseOptimizer` (``num_samples``, ``max_iter``, ``tol``, ...).

    Example: the ask / tell loop on ``||w - 1||^2`` (unbatched: ``(S, N)`` asked, ``(S,)`` told)

    >>> opt = CEM(torch.zeros(3), torch.ones(3), num_samples=20, seed=0)
    >>> while not opt.stop():
    ...     w = opt.ask()  # (S, N)
    ...     opt.tell((w - 1).pow(2).sum(-1))  # (S,): one objective
    >>> bool((opt.result().mean - 1).abs().max() < 0.5)
    True
    """

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        elite_frac: float = 0.1,
        smoothing: float = 1.0,
        extra_var: float = 0.0,
        objective_weights=None,
        **kwargs,
    ) -> None:
        if "beta" in kwargs:
            raise TypeError("CEM is rank-based and takes no beta")
        super().__init__(mean, var, beta=1.0, **kwargs)
        if not 0 < elite_frac <= 1:
            raise ValueError(f"elite_frac must be in (0, 1], got {elite_frac}")
        if not 0 < smoothing <= 1:
            raise ValueError(f"smoothing must be in (0, 1], got {smoothing}")
        if not extra_var >= 0:
            raise ValueError(f"extra_var must be >= 0, got {extra_var}")
        self.num_elites = max(2, math.ceil(elite_frac * self.num_samples))
        if self.num_elites > self.num_samples:
            raise ValueError(f"{self.num_elites} elites need num_samples >= {self.num_elites}")
        self.smoothing = float(smoothing)
        self.extra_var = float(extra_var)
        self._set_objective_weights(objective_weights)

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        w = self._sample(self.var, self.num_samples)  # (B, S, N)
        costs = yield w  # (B, S, O)
        self._record_cost(slice(None), costs)
        total = self._total_cost(costs)  # (B, S)
        idx = total.topk(self.num_elites, dim=-1, largest=False).indices  # (B, E)
        elites = w.gather(1, idx[..., None].expand(-1, -1, self.num_weights))  # (B, E, N)
        elite_mean = elites.mean(1)  # (B, N)
        elite_var = (elites - elite_mean[:, None]).pow(2).mean(1)  # (B, N), maximum likelihood
        a = self.smoothing
        new_mean = (1 - a) * self.mean + a * elite_mean
        new_var = (1 - a) * self.var + a * elite_var + self.extra_var
        self._commit(new_mean, new_var)
