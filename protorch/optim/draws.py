"""The optimisers' standard normal draws, optionally made one ask ahead in a background thread.

Every ask of a batched optimiser draws ``eps (B, S, N)`` for all ``B`` problems, moving or not,
so that the numbers do not depend on which problems are still moving; on a CPU that draw (the
generator is serial) is a third of a PRO iteration once few problems are left. With
:meth:`NormalDraws.start_ahead` the draw that the next ask will most likely want (the one at the
same place in the iteration as in the previous iteration) is made in a background thread as
soon as an ask has taken its own, so a free core draws while the caller evaluates the samples.
A guess of the wrong shape is undone (the generator goes back to the state before it) and the
right draw made in its place: the numbers are always those of drawing in order, one ask at a
time, and :meth:`NormalDraws.get_state` is the state that order leaves.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor

import torch
from torch import Tensor

__all__ = ["NormalDraws"]

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """One background thread for every optimiser's draws (created at the first use)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="protorch-draws")
        return _POOL


class NormalDraws:
    """``N(0, 1)`` tensors from ``generator``, in the order asked."""

    def __init__(self, generator: torch.Generator) -> None:
        self.generator = generator
        self.ahead = False
        self._pending: tuple[tuple, Tensor, Future] | None = (
            None  # (what, state before it, the draw)
        )
        self._previous: list[
            tuple
        ] = []  # what was drawn in the previous iteration: (shape, dtype, device)
        self._current: list[tuple] = []  # and in this one

    def start_ahead(self) -> None:
        """Draw each next ask's numbers in a background thread from now on (a CPU
        generator only)."""
        self.ahead = self.generator.device.type == "cpu"

    def new_iteration(self) -> None:
        """Mark the start of an optimiser iteration (the guesses follow the previous one)."""
        if self._current:
            self._previous, self._current = self._current, []

    def draw(self, shape: tuple, dtype: torch.dtype, device) -> Tensor:
        """The next ``shape`` of standard normal numbers in ``dtype`` on ``device``."""
        what = (tuple(int(s) for s in shape), dtype, torch.device(device))
        eps = self._take(what)
        self._current.append(what)
        if self.ahead:
            k = len(self._current)
            guess = (
                self._previous[k]
                if k < len(self._previous)
                else (self._previous[0] if self._previous else what)
            )
            state = self.generator.get_state()
            self._pending = (guess, state, _pool().submit(self._randn, guess))
        return eps

    def _randn(self, what: tuple) -> Tensor:
        shape, dtype, device = what
        return torch.randn(shape, generator=self.generator, dtype=dtype, device=device)

    def _take(self, what: tuple) -> Tensor:
        if self._pending is not None:
            guess, state, future = self._pending
            self._pending = None
            eps = future.result()
            if guess == what:
                return eps
            self.generator.set_state(state)  # a wrong guess: as if it had not been drawn
        return self._randn(what)

    def cancel(self) -> None:
        """Undo a draw made ahead and not taken (the generator as drawing in order leaves it)."""
        if self._pending is not None:
            _, state, future = self._pending
            self._pending = None
            future.result()
            self.generator.set_state(state)

    def get_state(self) -> Tensor:
        """The generator's state as drawing in order leaves it (before a draw made ahead)."""
        return self._pending[1].clone() if self._pending is not None else self.generator.get_state()

    def set_state(self, state: Tensor) -> None:
        self.cancel()
        self.generator.set_state(state)
