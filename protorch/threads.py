"""``torch_threads(n)``: run a block with ``n`` intra-op CPU threads, then restore the old number.

Why it matters: torch's CPU kernels split work over an OpenMP pool of ``torch.get_num_threads()``
threads (one per core by default), and the experiments' tensors are small (``(B, S, T, D)`` with
``S = 100``), so every op ends in a barrier where the threads wait for each other. When another
program takes a core, the thread that lost it holds every barrier up until the scheduler gives
it a slice back, and the waiting threads spin; measured on a 2-core machine, the point-particle
experiment ran 15x slower with one competing process at 2 threads (see
``benchmarks/contention.py``). One thread per run has no barrier to wait at.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch

from .checks import check_int

__all__ = ["torch_threads"]


@contextmanager
def torch_threads(n: int | None) -> Iterator[int]:
    """Set ``torch.set_num_threads(n)`` for the block and restore the previous value after it
    (also when the block raises). ``n = None`` or ``0`` leaves torch's setting as it is (one
    thread per core unless ``OMP_NUM_THREADS`` says otherwise). Yields the number in effect."""
    previous = torch.get_num_threads()
    if n is None or n == 0:
        yield previous
        return
    n = check_int(n, "threads", 1)
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(previous)
