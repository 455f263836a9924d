"""Exact k-nearest-neighbour search over a growing set of points, for the sparse environment map.

:class:`NeighbourIndex` stores points ``(n, d)`` in insertion order (in blocks that are never
copied, :class:`~protorch.gp.storage.GrowingRows`) and answers "the ``k`` nearest stored points
of each query", exactly: the same neighbours, in the same order, as a stable sort of every squared
distance (:func:`~protorch.gp.kernels.sq_dist`), ties broken by insertion order. Two kinds:

* ``"kdtree"``: :class:`scipy.spatial.cKDTree` s over consecutive runs of the points plus a tail
  of the latest points, searched by brute force (a logarithmic method). When the tail reaches
  ``min_tree`` points it gets a tree of its own, merged with the trees before it that are no
  larger than it, as long as the merged tree holds at most ``max_tree`` points. With adds of a
  few points the trees' sizes fall geometrically (a binary counter): ``O(M / max_tree +
  log(max_tree / min_tree))`` trees, each point rebuilt ``O(log(max_tree / min_tree))`` times,
  and no add builds a tree of more than ``max_tree`` points (one tree over all points would
  grow with ``n``).
* ``"brute"``: every distance in torch (chunked over the queries); no index to maintain, and the
  kind to use on a GPU.

Each tree, and the brute-force part in each storage block, proposes ``k + margin`` candidates per
query, which are ranked by their exact squared distances from :func:`sq_dist` and a stable sort. A
query whose candidates may miss a point tied with its ``k``-th neighbour (duplicates, a symmetric
grid) falls back to the full stable sort, so the result never depends on the kind, on the order of
adds or on how the points are split into trees.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor, nn

from .kernels import sq_dist
from .storage import GrowingRows

__all__ = ["NeighbourIndex", "INDEX_KINDS"]

INDEX_KINDS = ("kdtree", "brute")
_MARGIN = 8  # candidates beyond k, so that ties at the k-th neighbour rarely need the fallback
_CHUNK = 1 << 22  # distances per brute-force block (32 MB in float64)


class _Tree(NamedTuple):
    start: int  # the tree holds the points start .. end - 1
    end: int
    tree: cKDTree


class NeighbourIndex(nn.Module):
    """The ``k`` nearest of the stored points ``(n, d)`` (module docstring).

    Args:
        dim: ``d``, the points' dimension.
        kind: ``"kdtree"`` or ``"brute"``.
        min_tree: the brute-force tail gets a k-d tree when it holds this many points.
        max_tree: no tree is built over more points (a batch add beyond it is split).
    """

    def __init__(
        self,
        dim: int,
        *,
        kind: str = "kdtree",
        min_tree: int = 1024,
        max_tree: int = 65536,
        dtype: torch.dtype = torch.float64,
        device=None,
    ) -> None:
        super().__init__()
        if kind not in INDEX_KINDS:
            raise ValueError(f"index must be one of {list(INDEX_KINDS)}, got {kind!r}")
        if not 1 <= int(min_tree) <= int(max_tree):
            raise ValueError(f"need 1 <= min_tree <= max_tree, got {min_tree!r} and {max_tree!r}")
        self.kind, self.min_tree, self.max_tree = kind, int(min_tree), int(max_tree)
        self.trees: list[_Tree] = []  # consecutive runs covering the points 0 .. n_tree - 1
        self.points = GrowingRows((dim,), dtype=dtype, device=device)  # (n, d)

    @property
    def n(self) -> int:
        """Stored points."""
        return self.points.n

    @property
    def n_tree(self) -> int:
        """The first ``n_tree`` points are in trees; the rest (the tail) are searched by brute
        force."""
        return self.trees[-1].end if self.trees else 0

    def add(self, P: Tensor) -> None:
        """Append ``P (B, d)`` (positions ``n .. n + B - 1``)."""
        self.points.append(P)
        while self.kind == "kdtree" and self.n - self.n_tree >= self.min_tree:
            lo = self.n_tree
            hi = min(self.n, lo + self.max_tree)
            while (
                self.trees
                and self.trees[-1].end - self.trees[-1].start <= hi - lo
                and hi - self.trees[-1].start <= self.max_tree
            ):
                lo = self.trees.pop().start  # merge the smaller trees before into this one
            data = (
                self.points.rows(lo, hi).detach().to("cpu", torch.float64).numpy().copy()
            )  # (hi - lo, d)
            self.trees.append(
                _Tree(lo, hi, cKDTree(data, balanced_tree=False))
            )  # unbalanced: builds 2x faster

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
        cands, cuts = (
            [],
            [],
        )  # per part: positions (q, c_p) and points (q, c_p, d); if it returned fewer than all,
        # the squared distance of its farthest candidate (q,), which must lie beyond the k-th
        # nearest
        if self.trees:  # all trees in numpy, one conversion
            q_np, idx_np, cut_np = Q.detach().to("cpu", torch.float64).numpy(), [], []  # (q, d)
            for t in self.trees:
                ct = min(c, t.end - t.start)
                dist, idx = t.tree.query(q_np, k=[*range(1, ct + 1)])  # (q, ct), (q, ct)
                idx_np.append(idx + t.start)
                if ct < t.end - t.start:
                    cut_np.append(dist[:, -1])
            cand = torch.as_tensor(np.concatenate(idx_np, 1), device=Q.device)  # (q, C_trees)
            cands.append((cand, self.points.take(cand)))
            if cut_np:
                cuts.append(torch.as_tensor(np.min(cut_np, 0), dtype=Q.dtype, device=Q.device) ** 2)
        for start, P in self.points.segments(self.n_tree):  # the tail, per storage block
            ct = min(c, P.shape[0])
            d2, idx = _brute_topk(Q, P, ct)  # (q, ct), (q, ct)
            cands.append((idx + start, P[idx]))
            if ct < P.shape[0]:
                cuts.append(d2[:, -1])
        cand, pts = (
            (torch.cat(x, 1) for x in zip(*cands)) if len(cands) > 1 else cands[0]
        )  # (q, C), (q, C, d)
        d2c = sq_dist(Q[:, None], pts)[:, 0]  # (q, C)
        if not cuts:
            return cand, d2c, torch.ones(Q.shape[0], dtype=torch.bool, device=Q.device)
        rk = torch.kthvalue(d2c, k, dim=1).values  # (q,) the k-th smallest squared distance
        cut = cuts[0] if len(cuts) == 1 else torch.stack(cuts).amin(0)  # (q,)
        return cand, d2c, cut > rk * (1 + 1e-9) + 1e-300

    def _full_sort(self, Q: Tensor, k: int) -> Tensor:
        return torch.sort(sq_dist(Q, self.points.rows()), dim=1, stable=True).indices[
            :, :k
        ]  # (b, k)


def _brute_topk(Q: Tensor, P: Tensor, c: int) -> tuple[Tensor, Tensor]:
    """The ``c`` smallest squared distances from each query to ``P (p, d)``, chunked:
    ``(q, c)`` values in ascending order and their positions."""
    rows = max(1, _CHUNK // max(P.shape[0], 1))
    vals, idx = [], []
    for s in range(0, Q.shape[0], rows):
        v, i = torch.topk(
            sq_dist(Q[s : s + rows], P), c, dim=1, largest=False, sorted=True
        )  # (rows, c)
        vals.append(v)
        idx.append(i)
    return torch.cat(vals), torch.cat(idx)


def _sort_by_position(cand: Tensor, d2: Tensor) -> tuple[Tensor, Tensor]:
    """Candidates ``(q, C)`` in ascending position (so a stable sort breaks ties by insertion)."""
    cand, perm = torch.sort(cand, dim=1)
    return cand, d2.gather(1, perm)
