"""Exact k-nearest-neighbour search over a growing set of points, for the sparse environment map.

:class:`NeighbourIndex` stores points ``(n, d)`` in insertion order and answers "the ``k``
nearest stored points of each query", exactly: the same neighbours, in the same order, as a
stable sort of every squared distance (:func:`~protorch.gp.kernels.sq_dist`), ties broken by
insertion order. Two kinds:

* ``"kdtree"``: a :class:`scipy.spatial.cKDTree` over the first ``n_tree`` points plus a tail
  of the points added since, searched by brute force. ``add`` appends to the tail in ``O(B)``
  and rebuilds the tree (``O(n log n)``, 30 to 90 ms at ``n = 100,000``, ``d = 4``) only when the
  tail outgrows ``max(min_tail, tail_fraction * n_tree)``, so adds cost amortised ``O(1)``.
* ``"brute"``: every distance in torch (chunked over the queries); no index to maintain, and the
  kind to use on a GPU.

Either kind proposes ``k + margin`` candidates per query, which are ranked by their exact squared
distances from :func:`sq_dist` and a stable sort. A query whose candidates may miss a point tied
with its ``k``-th neighbour (duplicates, a symmetric grid) falls back to the full stable sort,
so the result never depends on the kind, on the order of adds or on when the tree was rebuilt.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor, nn

from .kernels import sq_dist

__all__ = ["NeighbourIndex", "INDEX_KINDS"]

INDEX_KINDS = ("kdtree", "brute")
_MARGIN = 8  # candidates beyond k, so that ties at the k-th neighbour rarely need the fallback
_CHUNK = 1 << 22  # distances per brute-force block (32 MB in float64)


class NeighbourIndex(nn.Module):
    """The ``k`` nearest of the stored points ``(n, d)`` (module docstring).

    Args:
        dim: ``d``, the points' dimension.
        kind: ``"kdtree"`` or ``"brute"``.
        min_tail, tail_fraction: the k-d tree is rebuilt when more than
            ``max(min_tail, tail_fraction * n_tree)`` points were added since the last build.
    """

    def __init__(self, dim: int, *, kind: str = "kdtree", min_tail: int = 1024, tail_fraction: float = 0.25,
                 dtype: torch.dtype = torch.float64, device=None) -> None:
        super().__init__()
        if kind not in INDEX_KINDS:
            raise ValueError(f"index must be one of {list(INDEX_KINDS)}, got {kind!r}")
        self.kind, self.min_tail, self.tail_fraction = kind, int(min_tail), float(tail_fraction)
        self.n = 0  # stored points
        self.n_tree = 0  # the first n_tree points are in the tree
        self.tree: cKDTree | None = None
        self.register_buffer("points", torch.zeros(16, dim, dtype=dtype, device=device))  # (cap, d)

    @property
    def stored(self) -> Tensor:
        return self.points[: self.n]  # (n, d)

    def add(self, P: Tensor) -> None:
        """Append ``P (B, d)`` (positions ``n .. n + B - 1``)."""
        b = P.shape[0]
        if self.n + b > self.points.shape[0]:
            grown = torch.empty(max(self.n + b, 2 * self.points.shape[0]), self.points.shape[1],
                                dtype=self.points.dtype, device=self.points.device)  # (cap, d), rows past n unread
            grown[: self.n] = self.stored
            self.points = grown
        self.points[self.n : self.n + b] = P
        self.n += b
        if self.kind == "kdtree" and self.n - self.n_tree > max(self.min_tail, self.tail_fraction * self.n_tree):
            self.rebuild()

    def rebuild(self) -> None:
        """Put every stored point into the k-d tree (an unbalanced build: about twice as fast,
        queries as fast at 4 to 6 dimensions)."""
        data = self.stored.detach().to("cpu", torch.float64).numpy().copy()  # (n, d)
        self.tree, self.n_tree = cKDTree(data, balanced_tree=False), self.n

    def query(self, Q: Tensor, k: int) -> Tensor:
        """``Q (q, d)`` -> positions ``(q, min(k, n))`` of the nearest stored points, nearest
        first, ties by insertion order."""
        k = min(int(k), self.n)
        c = min(k + _MARGIN, self.n)  # candidates per query
        cand, d2, complete = self._candidates(Q, c, k)  # (q, C) positions, (q, C), (q,) bool
        cand, d2 = _sort_by_position(cand, d2)
        order = torch.sort(d2, dim=1, stable=True).indices[:, :k]  # (q, k)
        pos = cand.gather(1, order)  # (q, k)
        if not bool(complete.all()):  # a tie at the k-th neighbour may lie outside the candidates
            bad = (~complete).nonzero()[:, 0]  # (b,)
            pos[bad] = self._full_sort(Q[bad], k)
        return pos

    # ------------------------------------------------------------------ helpers
    def _candidates(self, Q: Tensor, c: int, k: int) -> tuple[Tensor, Tensor, Tensor]:
        """``(q, C)`` candidate positions holding each query's ``k`` nearest, their ``(q, C)``
        squared distances, and ``(q,)`` whether they surely hold every point tied with the
        ``k``-th (else :meth:`_full_sort` decides)."""
        parts, radii = [], []  # per part: positions (q, c_p), the farthest candidate's sq. distance (q,)
        if self.n_tree:
            ct = min(c, self.n_tree)
            dist, idx = self.tree.query(Q.detach().to("cpu", torch.float64).numpy(), k=[*range(1, ct + 1)])
            parts.append((torch.as_tensor(np.asarray(idx), device=Q.device), ct, self.n_tree))
            radii.append(torch.as_tensor(np.asarray(dist)[:, -1], dtype=Q.dtype, device=Q.device) ** 2)
        if self.n > self.n_tree:
            ct = min(c, self.n - self.n_tree)
            d2, idx = _brute_topk(Q, self.stored[self.n_tree :], ct)  # (q, ct), (q, ct)
            parts.append((idx + self.n_tree, ct, self.n - self.n_tree))
            radii.append(d2[:, -1])
        cand = torch.cat([p[0] for p in parts], 1)  # (q, C)
        d2c = sq_dist(Q[:, None], self.stored[cand])[:, 0]  # (q, C)
        rk = torch.kthvalue(d2c, k, dim=1).values  # (q,) the k-th smallest squared distance
        complete = torch.ones(Q.shape[0], dtype=torch.bool, device=Q.device)  # (q,)
        for (_, ct, size), r in zip(parts, radii):
            if ct < size:  # a part that returned fewer than all its points: its cut-off must lie beyond rk
                complete &= r > rk * (1 + 1e-9) + 1e-300
        return cand, d2c, complete

    def _full_sort(self, Q: Tensor, k: int) -> Tensor:
        return torch.sort(sq_dist(Q, self.stored), dim=1, stable=True).indices[:, :k]  # (b, k)


def _brute_topk(Q: Tensor, P: Tensor, c: int) -> tuple[Tensor, Tensor]:
    """The ``c`` smallest squared distances from each query to ``P (p, d)``, chunked:
    ``(q, c)`` values in ascending order and their positions."""
    rows = max(1, _CHUNK // max(P.shape[0], 1))
    vals, idx = [], []
    for s in range(0, Q.shape[0], rows):
        v, i = torch.topk(sq_dist(Q[s : s + rows], P), c, dim=1, largest=False, sorted=True)  # (rows, c)
        vals.append(v)
        idx.append(i)
    return torch.cat(vals), torch.cat(idx)


def _sort_by_position(cand: Tensor, d2: Tensor) -> tuple[Tensor, Tensor]:
    """Candidates ``(q, C)`` in ascending position (so a stable sort breaks ties by insertion)."""
    cand, perm = torch.sort(cand, dim=1)
    return cand, d2.gather(1, perm)
