"""Rows that grow without being copied: the storage of the environment maps and of the sparse
map's nearest-neighbour index.

:class:`GrowingRows` holds ``n`` rows ``(n, *shape)`` in a list of blocks. A block is never moved
or copied once allocated: when the last one is full, ``append`` allocates a new block as large as
all the others together (at least ``min_block`` rows), so ``M`` rows take ``O(log M)`` blocks,
at most twice their memory in address space (untouched rows of a CPU block are not resident),
and no add pays for copying the rows before it (a single array that doubles copies them all). Reads:
:meth:`rows` (a contiguous range),
:meth:`segments` (the same range as views, one per block) and :meth:`take` (a gather by row).
"""

from __future__ import annotations

from bisect import bisect_right
from itertools import accumulate
from typing import Iterator, cast

import torch
from torch import Tensor, nn

__all__ = ["GrowingRows"]


class GrowingRows(nn.Module):
    """Rows ``(n, *shape)`` in blocks of geometric sizes (module docstring); the blocks are
    buffers (``b0``, ``b1``, ...), so ``.to(device)`` moves them.

    Args:
        shape: the shape of one row.
        min_block: rows of the smallest block.
    """

    def __init__(
        self,
        shape: tuple[int, ...] = (),
        *,
        dtype: torch.dtype = torch.float64,
        device=None,
        min_block: int = 1024,
    ) -> None:
        super().__init__()
        if int(min_block) < 1:
            raise ValueError(f"min_block must be >= 1, got {min_block!r}")
        self.shape, self.min_block = tuple(int(s) for s in shape), int(min_block)
        self.n = 0  # rows stored
        self.starts = [0]  # the first row of each block
        self.register_buffer(
            "b0", torch.empty(0, *self.shape, dtype=dtype, device=device)
        )  # (cap_0, *shape)

    @property
    def dtype(self) -> torch.dtype:
        return self.b0.dtype

    @property
    def device(self) -> torch.device:
        return self.b0.device

    @property
    def blocks(self) -> list[Tensor]:
        return [self._block(i) for i in range(len(self.starts))]

    @property
    def capacity(self) -> int:
        return self.capacity_of(len(self.starts) - 1)

    def extra_repr(self) -> str:
        return (
            f"shape={self.shape}, n={self.n}, blocks={len(self.starts)}, capacity={self.capacity}"
        )

    def append(self, *parts: Tensor) -> None:
        """Append rows ``n .. n + B - 1``: ``X (B, *shape)``, or ``(B, w_i)`` parts whose columns
        together make rows of width ``w`` (written in place, never concatenated first)."""
        if len(parts) == 1 and tuple(parts[0].shape[1:]) == self.shape:
            cols: list[tuple[int, int | None, Tensor]] = [(0, None, parts[0])]  # whole rows
        elif (
            len(self.shape) == 1
            and all(p.ndim == 2 for p in parts)
            and sum(p.shape[1] for p in parts) == self.shape[0]
            and len({p.shape[0] for p in parts}) == 1
        ):
            edges = [0, *accumulate(p.shape[1] for p in parts)]
            cols = list(zip(edges, edges[1:], parts))  # (first column, end column, (B, w_i))
        else:
            raise ValueError(
                f"rows must have shape (B, {', '.join(map(str, self.shape))}), got "
                f"{' + '.join(str(tuple(p.shape)) for p in parts)}"
            )
        done, b = 0, parts[0].shape[0]
        while done < b:
            if self.n == self.capacity:
                self._new_block(b - done)
            last = len(self.starts) - 1
            blk, s = self._block(last), self.starts[last]
            take = min(b - done, s + blk.shape[0] - self.n)
            rows = blk[self.n - s : self.n - s + take]  # (take, *shape) view
            for a, z, p in cols:
                (rows if z is None else rows[:, a:z]).copy_(p[done : done + take])
            done, self.n = done + take, self.n + take

    def _new_block(self, need: int) -> None:
        size = max(need, self.capacity, self.min_block)
        block = torch.empty(
            size, *self.shape, dtype=self.dtype, device=self.device
        )  # rows past n are never read
        if self.capacity == 0:  # the empty first block is replaced
            self.b0 = block
        else:
            self.register_buffer(f"b{len(self.starts)}", block)
            self.starts.append(self.n)

    def segments(self, lo: int = 0, hi: int | None = None) -> Iterator[tuple[int, Tensor]]:
        """Rows ``lo .. hi - 1`` as ``(first row, view (r, *shape))`` per block they span."""
        hi = self.n if hi is None else hi
        for s, blk in zip(self.starts, self.blocks):
            a, z = max(lo, s), min(hi, s + blk.shape[0])
            if a < z:
                yield a, blk[a - s : z - s]

    def rows(self, lo: int = 0, hi: int | None = None) -> Tensor:
        """Rows ``lo .. hi - 1`` ``(r, *shape)``, contiguous: a view if one block holds them all."""
        parts = [v for _, v in self.segments(lo, hi)]
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return self.b0[:0]
        return torch.cat(parts)

    def take(self, idx: Tensor) -> Tensor:
        """``idx (...)`` row numbers ``< n`` -> ``(..., *shape)``: one indexing per block hit."""
        if len(self.starts) > 1 and idx.numel():
            lo, hi = idx.aminmax()
            first = bisect_right(self.starts, int(lo)) - 1
            if int(hi) < self.capacity_of(
                first
            ):  # all in one block (the common case): one indexing
                return self._block(first)[idx - self.starts[first]]
            return self._take_blocks(idx)
        return self.b0[idx]

    def _block(self, i: int) -> Tensor:
        """Block ``i``'s buffer ``(capacity_i, *shape)``."""
        return cast(Tensor, self._buffers[f"b{i}"])

    def capacity_of(self, i: int) -> int:
        """One past the last row block ``i`` can hold."""
        return self.starts[i] + self._block(i).shape[0]

    def _take_blocks(self, idx: Tensor) -> Tensor:
        flat = idx.reshape(-1)  # (I,)
        starts = torch.tensor(self.starts, device=flat.device)  # (K,)
        which = torch.searchsorted(starts, flat, right=True) - 1  # (I,) block of each row
        order = torch.argsort(which, stable=True)  # (I,) rows grouped by block
        local = (flat - starts[which])[order]  # (I,) row within its block
        counts = torch.bincount(which, minlength=len(self.starts)).tolist()
        parts, a = [], 0
        for blk, c in zip(self.blocks, counts):
            if c:
                parts.append(blk[local[a : a + c]])
                a += c
        out = torch.empty(
            flat.shape[0], *self.shape, dtype=self.dtype, device=self.device
        )  # (I, *shape)
        out[order] = torch.cat(parts)
        return out.reshape(*idx.shape, *self.shape)
