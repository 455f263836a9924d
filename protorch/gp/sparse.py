"""Backend ``"sparse"``: local GPs over each query's nearest known environments of its label.

Memory ``O(M (d + 2N))``: the data themselves plus, per label, the positions of its rows and a
nearest-neighbour index (:class:`~protorch.gp.neighbours.NeighbourIndex`, k-d trees by
default); no ``M x M`` matrix, no factor kept. ``add`` appends to storage blocks that are never
copied (:class:`~protorch.gp.storage.GrowingRows`) and now and then builds a k-d tree over at
most 65,536 points, so no single add grows with ``M`` beyond that. A query
finds its ``k`` nearest known environments of its label and solves Eq. 7 and 8 on them: one
batched ``k x k`` Cholesky per weight (each weight has its own noise ``VAR[:, n]``), ``O(k^3 N)``
whatever ``M``.

Two modes, by ``nearest_k``:

* ``nearest_k = k`` (the authors' local GPs over the 30 nearest of the query's class, as every
  backend reads ``nearest_k``): prior mean and average variance are those of the ``k``
  neighbours. The same neighbours and the same solve as the exact backends with ``nearest_k``,
  only found with an index.
* ``nearest_k = None`` (an approximation of the exact map): the prior mean ``mu0_n`` and the
  average variance ``vbar_n`` are those of the label's whole data (running sums), and the solve
  uses the ``neighbours`` nearest environments; it equals Eq. 7 and 8 on all data whenever a
  label has at most ``neighbours`` environments, and drops the far ones otherwise (their kernel
  values at the query are small). Its error against the exact map is measured by
  ``benchmarks/gp_scaling.py --accuracy``.

``approx_var`` has no effect: the variance is already an exact solve on the neighbours.
"""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor, nn

from .base import EnvMap
from .kernels import local_gp
from .neighbours import INDEX_KINDS, NeighbourIndex
from .storage import GrowingRows

__all__ = ["SparseEnvMap"]

_WORK = 1 << 22  # elements of the (queries, N, k, k) systems solved at once: 32 MB in float64


class _LabelIndex(nn.Module):
    """One label's rows of the map's storage, their nearest-neighbour index and running sums."""

    mu_sum: Tensor  # (N,) registered buffers
    var_sum: Tensor  # (N,)

    def __init__(self, d: int, n: int, *, kind: str, dtype, device) -> None:
        super().__init__()
        self.index = NeighbourIndex(d, kind=kind, dtype=dtype, device=device)
        self.rows = GrowingRows((), dtype=torch.long, device=device)  # (count,) storage rows
        self.register_buffer("mu_sum", torch.zeros(n, dtype=dtype, device=device))  # (N,)
        self.register_buffer("var_sum", torch.zeros(n, dtype=dtype, device=device))  # (N,)

    @property
    def count(self) -> int:
        return self.index.n

    def extend(self, rows: Tensor, E: Tensor, MU: Tensor, VAR: Tensor) -> None:
        """Append storage ``rows (B,)`` holding ``E (B, d), MU (B, N), VAR (B, N)``."""
        self.rows.append(rows)
        self.mu_sum += MU.sum(0)
        self.var_sum += VAR.sum(0)
        self.index.add(E)

    def nearest_rows(self, Eq: Tensor, k: int) -> Tensor:
        """``Eq (Q, d)`` -> storage rows ``(Q, min(k, count))`` of the nearest, nearest first."""
        return self.rows.take(self.index.query(Eq, k))


class SparseEnvMap(EnvMap):
    """Local-GP backend for large data sets (module docstring).

    Args:
        nearest_k: the authors' local GPs on the ``k`` nearest (their prior mean); ``None``:
            approximate the exact map (the label's prior mean, ``neighbours`` in the solve).
        neighbours: environments per solve when ``nearest_k`` is ``None``.
        index: ``"kdtree"`` (scipy's ``cKDTree``, CPU) or ``"brute"`` (torch, any device):
            the same neighbours either way.

    Example: fit ``M = 6`` environments ``(M, d)`` with their weight means and variances
    ``(M, N)``, predict at two

    >>> g = torch.Generator().manual_seed(0)
    >>> E, MU = torch.rand(6, 2, generator=g), torch.rand(6, 4, generator=g)
    >>> env_map = SparseEnvMap(alpha=1.0).fit(E, MU, torch.full((6, 4), 0.1))
    >>> mu, var = env_map.predict(E[:2])  # (Q, N) each
    >>> mu.shape, bool((var > 0).all())
    (torch.Size([2, 4]), True)
    """

    backend = "sparse"

    def __init__(
        self,
        alpha: float,
        *,
        nearest_k: int | None = None,
        neighbours: int = 32,
        index: str = "kdtree",
        dtype: torch.dtype = torch.float64,
        device=None,
    ) -> None:
        super().__init__(alpha, nearest_k=nearest_k, dtype=dtype, device=device)
        if isinstance(neighbours, bool) or int(neighbours) != neighbours or int(neighbours) < 1:
            raise ValueError(f"neighbours must be an int >= 1, got {neighbours!r}")
        if index not in INDEX_KINDS:
            raise ValueError(f"index must be one of {list(INDEX_KINDS)}, got {index!r}")
        self.neighbours, self.index = int(neighbours), index
        self.groups = nn.ModuleDict()

    def options(self) -> dict:
        return {**super().options(), "neighbours": self.neighbours, "index": self.index}

    def _keeps_groups(self) -> bool:
        return True  # the per-label indexes serve both modes

    def _reset_groups(self) -> None:
        self.groups = nn.ModuleDict()

    def _has_group(self, g: int) -> bool:
        return str(g) in self.groups

    def _group_fit(self, g, E, MU, VAR) -> None:
        grp = _LabelIndex(
            E.shape[1], MU.shape[1], kind=self.index, dtype=self.dtype, device=self.device
        )
        grp.extend(self._new_rows(g), E, MU, VAR)
        self.groups[str(g)] = grp

    def _group_add(self, g, E, MU, VAR) -> None:
        cast(_LabelIndex, self.groups[str(g)]).extend(
            self._new_rows(g), E, MU, VAR
        )  # (B_g,) rows the base class stored

    def _group_predict(self, g, Eq, *, need_var, approx_var):
        grp = self.groups[str(g)]
        local = self.nearest_k is not None
        k = self.nearest_k if local else self.neighbours
        mu = torch.empty(
            Eq.shape[0], self.num_weights, dtype=self.dtype, device=self.device
        )  # (Q, N)
        var = torch.empty_like(mu) if need_var else None  # (Q, N)
        prior = None if local else (grp.mu_sum / grp.count, grp.var_sum / grp.count)  # (N,), (N,)
        chunk = max(1, _WORK // (self.num_weights * min(k, grp.count) ** 2))  # queries per solve
        for s in range(0, Eq.shape[0], chunk):
            e = Eq[s : s + chunk]  # (q, d)
            rows = grp.nearest_rows(e, k)  # (q, k)
            mu0, vbar = (
                (None, None) if local else (p.expand(e.shape[0], -1) for p in prior)
            )  # (q, N)
            m_c, v_c = local_gp(
                *self._take(rows), e, self.alpha, need_var=need_var, mu0=mu0, vbar=vbar
            )
            mu[s : s + chunk] = m_c
            if need_var:
                var[s : s + chunk] = v_c
        return mu, var

    def _predict_subsets(self, Es, MUs, VARs, Eq, *, need_var):
        return local_gp(Es, MUs, VARs, Eq, self.alpha, need_var=need_var)
