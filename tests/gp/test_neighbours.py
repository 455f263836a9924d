"""protorch.gp.neighbours: the k nearest stored points, exactly those of a stable sort of every
distance (ties by insertion order), whatever the index kind and however the points were added."""

from __future__ import annotations

import pytest
import torch

from protorch.gp.kernels import sq_dist
from protorch.gp.neighbours import NeighbourIndex

F64 = torch.float64


def _points(seed=0):
    """Random points, exact duplicates and a regular grid (many equidistant neighbours)."""
    g = torch.Generator().manual_seed(seed)
    rand = torch.rand(300, 3, generator=g, dtype=F64)
    axis = torch.linspace(0, 1, 5, dtype=F64)
    grid = torch.cartesian_prod(axis, axis, axis)  # (125, 3)
    P = torch.cat([rand, rand[:40], grid, grid[:30]])  # (495, 3)
    return P[torch.randperm(P.shape[0], generator=g)]


def _stable_nearest(Q, P, k):
    return torch.sort(sq_dist(Q, P), dim=1, stable=True).indices[:, :k]


@pytest.mark.parametrize("kind", ["kdtree", "brute"])
def test_query_equals_a_stable_sort_of_every_distance(kind):
    P = _points()
    Q = torch.cat(
        [
            P[:20],
            torch.rand(30, 3, generator=torch.Generator().manual_seed(1), dtype=F64),
            torch.full((1, 3), 0.5, dtype=F64),
            torch.tensor([[0.125, 0.125, 0.5]], dtype=F64),
        ]
    )
    index = NeighbourIndex(3, kind=kind, min_tree=16, max_tree=64)
    for s, e in [(0, 1), (1, 7), (7, 60), (60, 61), (61, 300), (300, 495)]:
        index.add(P[s:e])
        for k in (1, 5, 30, 1000):  # k beyond the stored points returns them all
            got = index.query(Q, k)
            assert torch.equal(got, _stable_nearest(Q, P[:e], k)), (kind, e, k)
    assert index.n == 495


def test_ties_beyond_the_candidates_fall_back_to_the_full_sort():
    """40 copies of one point: the 3 nearest of a query at it are its first three copies."""
    P = torch.cat(
        [
            torch.rand(100, 2, dtype=F64, generator=torch.Generator().manual_seed(2)) + 1,
            torch.zeros(40, 2, dtype=F64),
        ]
    )
    index = NeighbourIndex(2, min_tree=1, max_tree=1000)
    index.add(P)
    assert index.n_tree == 140 and len(index.trees) == 1
    assert index.query(torch.zeros(1, 2, dtype=F64), 3).tolist() == [[100, 101, 102]]


def test_trees_of_falling_sizes_none_beyond_max_tree():
    """The tail gets a tree at min_tree points, merged with the smaller trees before it (a binary
    counter) up to max_tree points; a batch beyond max_tree is split."""
    index = NeighbourIndex(2, min_tree=4, max_tree=16)
    P = torch.rand(80, 2, dtype=F64, generator=torch.Generator().manual_seed(3))
    sizes = []
    for i in range(40):
        index.add(P[i : i + 1])
        sizes.append([t.end - t.start for t in index.trees])
    assert sizes[2] == [] and sizes[3] == [4]  # 3 points: all in the tail; 4: a tree
    assert sizes[7] == [8] and sizes[11] == [8, 4] and sizes[15] == [16] and sizes[31] == [16, 16]
    assert sizes[39] == [16, 16, 8] and index.n_tree == 40
    assert all(a.end == b.start for a, b in zip(index.trees, index.trees[1:]))  # consecutive runs
    index.add(P[40:])
    assert [t.end - t.start for t in index.trees] == [16, 16, 8, 16, 16, 8] and index.n_tree == 80
    brute = NeighbourIndex(2, kind="brute", min_tree=1)
    brute.add(P)
    assert brute.trees == [] and brute.n_tree == 0


def test_bad_kind():
    with pytest.raises(ValueError, match="index must be one of"):
        NeighbourIndex(2, kind="faiss")
    with pytest.raises(ValueError, match="min_tree <= max_tree"):
        NeighbourIndex(2, min_tree=10, max_tree=5)
