"""The speed scripts' one timing helper (no protorch import): per-call wall seconds after a warm-up,
calls of several implementations taking turns, a time budget per item, wall and CPU stopwatches.

Scripts run as ``python benchmarks/<script>.py`` import it as ``from _timing import ...`` (the
script's folder is on ``sys.path``). On a machine shared with other work, compare the median (or
the best) of several calls, and CPU seconds of a one-thread process where the load varies.
"""

from __future__ import annotations

import resource
import statistics
import time
from typing import Callable, Iterable, Sequence

__all__ = [
    "Stopwatch",
    "best_s",
    "call_times",
    "cpu_seconds",
    "median_s",
    "per_item",
    "percentile",
    "turns",
]


def call_times(
    fn: Callable[[], object],
    repeats: int,
    *,
    warmup: int = 1,
    sync: Callable[[], None] | None = None,
) -> list[float]:
    """Wall seconds of each of ``repeats`` calls of ``fn()`` after ``warmup`` untimed calls;
    ``sync`` (e.g. ``torch.cuda.synchronize``) runs before each clock read."""
    if repeats < 1 or warmup < 0:
        raise ValueError(f"need repeats >= 1 and warmup >= 0, got {repeats}, {warmup}")
    for _ in range(warmup):
        fn()
    if sync is not None:
        sync()
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        if sync is not None:
            sync()
        out.append(time.perf_counter() - t)
    return out


def median_s(fn: Callable[[], object], repeats: int, **kw) -> float:
    """The median of :func:`call_times` (seconds per call)."""
    return statistics.median(call_times(fn, repeats, **kw))


def best_s(fn: Callable[[], object], repeats: int, **kw) -> float:
    """The fastest of :func:`call_times` (seconds per call)."""
    return min(call_times(fn, repeats, **kw))


def turns(fns: Sequence[Callable[[], object]], repeats: int) -> tuple[list[list[float]], list]:
    """``(seconds per call of each fn, each fn's warm-up result)``: one warm-up call each, then
    ``repeats`` rounds in which every ``fn`` is called once, in order on even rounds and in reverse
    on odd ones, so that all of them see the same load on a shared machine."""
    if repeats < 1:
        raise ValueError(f"need repeats >= 1, got {repeats}")
    outs = [f() for f in fns]
    times: list[list[float]] = [[] for _ in fns]
    order = list(range(len(fns)))
    for i in range(repeats):
        for j in order if i % 2 == 0 else order[::-1]:
            t = time.perf_counter()
            fns[j]()
            times[j].append(time.perf_counter() - t)
    return times, outs


def per_item(
    fn: Callable[[object], object], items: Iterable, budget_s: float, *, at_least: int = 3
) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds of ``fn(item)`` per item, stopping once ``budget_s`` has passed after
    at least ``at_least`` items. A one-thread process's CPU time is what a call costs an idle
    core."""
    wall: list[float] = []
    cpu: list[float] = []
    start = time.perf_counter()
    for i, item in enumerate(items):
        t, c = time.perf_counter(), time.process_time()
        fn(item)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        if i + 1 >= at_least and time.perf_counter() - start > budget_s:
            break
    return wall, cpu


def percentile(xs: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0 to 100) of ``xs``, nearest rank."""
    if not xs or not 0 <= q <= 100:
        raise ValueError(f"need values and 0 <= q <= 100, got {len(xs)} values, q={q}")
    return sorted(xs)[min(len(xs) - 1, int(q / 100 * len(xs)))]


def cpu_seconds(children: bool = True) -> float:
    """User + system CPU seconds of this process (and of its finished children)."""
    s = resource.getrusage(resource.RUSAGE_SELF)
    total = s.ru_utime + s.ru_stime
    if children:
        c = resource.getrusage(resource.RUSAGE_CHILDREN)
        total += c.ru_utime + c.ru_stime
    return total


class Stopwatch:
    """``with Stopwatch() as sw: ...`` then ``sw.wall`` and ``sw.cpu`` (this process's CPU
    seconds, children included) of the block."""

    wall: float
    cpu: float

    def __enter__(self) -> Stopwatch:
        self._w, self._c = time.perf_counter(), cpu_seconds()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self._w
        self.cpu = cpu_seconds() - self._c
