"""protorch.gp.storage: rows appended in blocks that are never copied read back exactly as one
array, whatever the batch sizes and however they straddle the blocks."""

from __future__ import annotations

import pytest
import torch

from protorch.gp.storage import GrowingRows


def _filled(batches, shape=(3,), min_block=4):
    g = torch.Generator().manual_seed(0)
    store = GrowingRows(shape, min_block=min_block)
    data = [torch.randn(b, *shape, generator=g, dtype=torch.float64) for b in batches]
    for x in data:
        store.append(x)
    return store, torch.cat(data)


def test_reads_equal_one_array_across_block_boundaries():
    store, ref = _filled([1, 2, 1, 7, 0, 3, 13, 1, 1, 40, 2])  # 71 rows
    assert (
        store.n == 71 and len(store.blocks) > 3
    )  # 4, 4, 8, 16, 40: the batch of 40 gets its own block
    assert torch.equal(store.rows(), ref)
    for lo, hi in [(0, 4), (3, 5), (2, 30), (17, 71), (70, 71), (5, 5)]:
        assert torch.equal(store.rows(lo, hi), ref[lo:hi]), (lo, hi)
        got = [(s, v.shape[0]) for s, v in store.segments(lo, hi)]
        assert sum(r for _, r in got) == hi - lo and all(s >= lo for s, _ in got)
    idx = torch.randint(0, 71, (5, 9), generator=torch.Generator().manual_seed(1))
    assert torch.equal(store.take(idx), ref[idx])  # (5, 9, 3)
    assert store.take(torch.zeros(0, dtype=torch.long)).shape == (0, 3)


def test_parts_append_as_their_columns_side_by_side():
    store, ref = (
        GrowingRows((5,), min_block=4),
        torch.arange(50.0, dtype=torch.float64).reshape(10, 5),
    )
    for s, e in [(0, 3), (3, 9), (9, 10)]:
        store.append(ref[s:e, :1], ref[s:e, 1:3], ref[s:e, 3:])
    assert torch.equal(store.rows(), ref)


def test_blocks_are_never_moved_and_grow_geometrically():
    store = GrowingRows((), dtype=torch.long, min_block=8)
    store.append(torch.arange(5))
    first = store.blocks[0].data_ptr()
    for i in range(5, 1000):
        store.append(torch.tensor([i]))
    assert store.blocks[0].data_ptr() == first  # appended after it, never copied
    assert [b.shape[0] for b in store.blocks] == [8, 8, 16, 32, 64, 128, 256, 512]
    assert store.capacity == 1024 and torch.equal(store.rows(), torch.arange(1000))


def test_to_moves_every_block():
    store, ref = _filled([5, 5, 5])
    store = store.to(torch.float32)
    assert all(b.dtype == torch.float32 for b in store.blocks) and store.dtype == torch.float32
    assert torch.equal(store.rows(), ref.float())


def test_bad_rows():
    store = GrowingRows((3,))
    with pytest.raises(ValueError, match=r"shape \(B, 3\)"):
        store.append(torch.zeros(2, 4))
    with pytest.raises(ValueError, match=r"shape \(B, 3\)"):
        store.append(torch.zeros(2, 1), torch.zeros(3, 2))  # rows differ
    with pytest.raises(ValueError, match="min_block"):
        GrowingRows((3,), min_block=0)
