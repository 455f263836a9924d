"""CMA-ES from pycma (``cma``), wrapped into protorch's ask / tell contract (not re-implemented)."""

from __future__ import annotations

from typing import Generator

import numpy as np
import torch
from torch import Tensor

from .base import BaseOptimizer

__all__ = ["CMAES"]


class CMAES(BaseOptimizer):
    """Hansen's CMA-ES as implemented by pycma, one ``cma.CMAEvolutionStrategy`` per problem.

    Each strategy starts from the same Gaussian as the other optimisers: mean ``mean[b]`` and
    per-weight stds ``sqrt(var[b])`` (pycma's ``x0 = mean``, ``sigma0 = 1``,
    ``CMA_stds = std``), with ``popsize = num_samples``. One iteration asks every strategy for
    its ``S`` candidates (``(B, S, N)`` in one tensor), and tells each its total costs
    ``sum_o c_o * cost_o``. Afterwards ``mean`` is pycma's mean and ``var`` the diagonal of its
    covariance, ``(sigma * sigma_vec)^2 * diag(C)`` (``es.stds ** 2``); the full ``C`` lives in
    :attr:`strategies`. A problem stops by the contract's rule (``max_iter``, ``tol`` /
    ``window``) and, with ``pycma_stop`` (default), also once its strategy's ``stop()`` fires
    (``tolfun``, ``tolx``, flat fitness, ...; the reasons land in :attr:`stop_reasons`): pycma
    run past its own termination shrinks ``sigma`` to underflow and then blows up on the flat
    fitness that follows.

    Sampling uses one ``numpy.random.Generator`` per problem seeded from ``(seed, b)`` (pycma's
    ``randn`` option), so runs are reproducible, problems are independent, and numpy's global
    random state is not touched. Rank-based: there is no ``beta``. On small problems numpy's
    BLAS threads and torch's threads can fight over the cores (``OPENBLAS_NUM_THREADS=1`` helps).

    Args:
        objective_weights: ``(O,)``, default all ones: how objectives combine into one cost.
        cma_options: extra pycma options (``cma.CMAOptions()`` lists them), e.g.
            ``{"CMA_diagonal": True}`` for separable CMA-ES or ``{"tolfun": 1e-6}``.
        pycma_stop: mark a problem converged when pycma's ``stop()`` fires (default True).
        Other arguments: :class:`BaseOptimizer`. ``var`` must be > 0.

    Needs pycma: ``pip install "protorch[peers]"`` (or ``pip install cma``).

    Example: the ask / tell loop on ``||w - 1||^2`` (unbatched: ``(S, N)`` asked, ``(S,)`` told)

    >>> opt = CMAES(torch.zeros(3), torch.ones(3), num_samples=10, seed=0)
    >>> while not opt.stop():
    ...     w = opt.ask()  # (S, N)
    ...     opt.tell((w - 1).pow(2).sum(-1))  # (S,): one objective
    >>> bool((opt.result().mean - 1).abs().max() < 0.05)
    True
    """

    can_restart = False  # its state is not per problem (global iteration, pooled or external state)

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        objective_weights=None,
        cma_options: dict | None = None,
        pycma_stop: bool = True,
        **kwargs,
    ) -> None:
        if "beta" in kwargs:
            raise TypeError("CMAES is rank-based and takes no beta")
        seed = kwargs.get("seed")
        super().__init__(mean, var, beta=1.0, **kwargs)
        try:
            import cma
        except ImportError as exc:  # pragma: no cover - the test extra installs it
            raise ImportError(
                'CMAES needs pycma: pip install "protorch[peers]" (or pip install cma)'
            ) from exc
        if bool((self.var <= 0).any()):
            raise ValueError("CMA-ES needs var > 0 in every weight (a zero std cannot be adapted)")
        self._set_objective_weights(objective_weights)
        options = dict(cma_options or {})
        reserved = {"CMA_stds", "popsize", "randn", "seed"} & set(options)
        if reserved:
            raise ValueError(
                f"cma_options may not set {sorted(reserved)}: they come from var, num_samples and "
                "seed"
            )
        self.pycma_stop = bool(pycma_stop)
        self.stop_reasons: list[dict] = [{} for _ in range(self.batch_size)]
        entropy = None if seed is None else [int(seed)]
        self.rngs: list[np.random.Generator] = []
        self.strategies = []
        mean64 = self.mean.detach().double().cpu().numpy()  # (B, N)
        std64 = self.var.detach().double().sqrt().cpu().numpy()  # (B, N)
        for b in range(self.batch_size):
            seq = np.random.SeedSequence(None if entropy is None else [*entropy, b])
            rng = np.random.Generator(np.random.PCG64(seq))
            opts = {
                "CMA_stds": std64[b],
                "popsize": self.num_samples,
                "seed": float("nan"),
                "randn": (lambda *shape, rng=rng: rng.standard_normal(shape)),
                "verbose": -9,
                "verb_disp": 0,
                "verb_log": 0,
                **options,
            }
            self.rngs.append(rng)
            self.strategies.append(cma.CMAEvolutionStrategy(mean64[b], 1.0, opts))

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        b_count, s, n = self.batch_size, self.num_samples, self.num_weights
        active = (~self.converged).tolist()
        x = np.repeat(self.mean.detach().double().cpu().numpy()[:, None], s, axis=1)  # (B, S, N)
        for b, es in enumerate(self.strategies):
            if active[b]:  # a converged problem is not asked (its costs are never read)
                x[b] = np.asarray(es.ask(), dtype=np.float64)
        w = torch.as_tensor(x, device=self.mean.device).to(self.mean.dtype)  # (B, S, N)
        costs = yield w  # (B, S, O)
        self._record_cost(slice(None), costs)
        total = self._total_cost(costs).double().cpu().numpy()  # (B, S)
        new_mean = np.empty((b_count, n))
        new_var = np.empty((b_count, n))
        for b, es in enumerate(self.strategies):
            if active[b]:
                es.tell(list(x[b]), total[b].tolist())
                self.stop_reasons[b] = dict(es.stop())
            new_mean[b] = es.mean
            new_var[b] = np.asarray(es.stds) ** 2
        self._commit(
            torch.as_tensor(new_mean, device=self.mean.device).to(self.mean.dtype),
            torch.as_tensor(new_var, device=self.mean.device).to(self.mean.dtype),
        )
        if self.pycma_stop:  # after this iteration's update, as the contract's own rule
            self.converged |= torch.tensor(
                [active[b] and bool(r) for b, r in enumerate(self.stop_reasons)],
                device=self.converged.device,
            )
