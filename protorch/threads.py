"""torch's CPU threads for a run: a fixed number, torch's own setting, or ``"auto"``.

Why it matters: torch's CPU kernels split work over an OpenMP pool of ``torch.get_num_threads()``
threads (one per core by default), and the experiments' tensors are small (``(B, S, T, D)`` with
``S = 100``), so every op ends in a barrier where the threads wait for each other. When another
program takes a core, the thread that lost it holds every barrier up until the scheduler gives
it a slice back (docs/contention.md has the measurements); on an idle machine more threads
help. ``"auto"`` takes the best of both: it measures how many cores other programs keep busy
(``/proc/stat`` between two readings,
minus this process's own CPU time) and uses the cores left, at least one; the loop re-chooses
before every step (:class:`ThreadGovernor`), so a competitor that starts or stops mid-run is
followed. Where ``/proc/stat`` cannot be read, ``"auto"`` is one thread.
"""

from __future__ import annotations

import contextvars
import math
import os
import time
from contextlib import contextmanager
from typing import Iterator

import torch

from .checks import check_int

__all__ = [
    "AUTO",
    "torch_threads",
    "one_thread",
    "ThreadGovernor",
    "LoadProbe",
    "available_cores",
    "threads_for",
    "core_budget",
    "beside_workers",
]

AUTO = "auto"
_PROBE_SECONDS = 0.2  # the first reading's window (later ones: the time since the previous choice)
_BUSY_MARGIN = 0.3  # cores of other load below which a core still counts as free
_OUTER: contextvars.ContextVar = contextvars.ContextVar(
    "protorch_threads", default=None
)  # the enclosing setting


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _machine_jiffies() -> tuple[int, int]:
    """``(busy, total)`` CPU jiffies of the whole machine since boot (``/proc/stat``)."""
    with open("/proc/stat") as f:
        vals = [
            int(x) for x in f.readline().split()[1:9]
        ]  # user nice system idle iowait irq softirq steal
    idle = vals[3] + vals[4]
    return sum(vals) - idle, sum(vals)


class LoadProbe:
    """Cores kept busy by other programs between two readings: the machine's busy CPU time minus
    this process's own (all its threads, spinning ones included), over the wall time."""

    def __init__(self) -> None:
        self.hz = os.sysconf("SC_CLK_TCK")
        self.last = self._read()

    def _read(self) -> tuple[int, int, float]:
        busy, total = _machine_jiffies()
        t = os.times()
        return busy, total, t.user + t.system

    def other_cores(self) -> float:
        """Cores busy with other programs since the previous reading (>= 0)."""
        busy, total, ours = now = self._read()
        b0, t0, o0 = self.last
        self.last = now
        ncpu = os.cpu_count() or 1
        wall = (total - t0) / ncpu  # jiffies of wall time
        if wall <= 0:
            return 0.0
        return max(0.0, ((busy - b0) - (ours - o0) * self.hz) / wall)


def core_budget() -> int:
    """The cores the enclosing thread setting lets a run use at once (threads of torch or worker
    processes): its number when it is fixed, else (``"auto"``, torch's default, no setting) the
    cores available to this process. ``threads=1`` keeps a run on one core."""
    outer = _OUTER.get()
    if outer is None or outer == AUTO or outer == 0:
        return available_cores()
    return int(outer)


def beside_workers(workers: int) -> int | str:
    """The thread setting for this process while ``workers`` one-thread worker processes run
    beside it: ``"auto"`` stays ``"auto"`` (it measures the workers as other programs' load), a
    fixed ``n`` becomes ``max(1, n - workers)``."""
    outer = _OUTER.get()
    if outer is None or outer == AUTO or outer == 0:
        return AUTO
    return max(1, int(outer) - int(workers))


def threads_for(other_cores: float, cores: int) -> int:
    """The threads to use with ``other_cores`` cores busy elsewhere: the free ones, at least 1."""
    return max(1, min(cores, cores - math.ceil(other_cores - _BUSY_MARGIN)))


class ThreadGovernor:
    """Sets torch's threads for a block and restores them after it; with ``"auto"``, :meth:`step`
    re-chooses from the load measured since the previous choice.

    ``threads``: an int >= 1, ``None`` (or 0: leave torch's setting) or ``"auto"``. Inside an
    enclosing governor (the app's ``threads`` setting around an experiment), ``"auto"`` takes the
    enclosing setting: a number chosen by the caller is kept."""

    def __init__(self, threads: int | str | None) -> None:
        outer = _OUTER.get()
        if threads == AUTO and outer is not None:
            threads = outer
        self.setting = threads
        self.auto = threads == AUTO
        self.fixed = (
            None
            if (self.auto or threads is None or threads == 0)
            else check_int(threads, "threads", 1)
        )
        self.previous = torch.get_num_threads()
        self.probe: LoadProbe | None = None

    def __enter__(self) -> "ThreadGovernor":
        self.previous = torch.get_num_threads()
        self.token = _OUTER.set(
            self.setting if (self.auto or self.fixed is not None) else _OUTER.get()
        )
        if self.fixed is not None:
            torch.set_num_threads(self.fixed)
        elif self.auto:
            try:
                self.probe = LoadProbe()
                time.sleep(_PROBE_SECONDS)
            except (
                OSError,
                ValueError,
            ):  # no /proc/stat (not Linux): one thread is safe everywhere
                self.probe = None
            self.step()
        return self

    def step(self) -> int:
        """Re-choose the number of threads (``"auto"`` only); returns the number in effect."""
        if self.auto:
            n = (
                1
                if self.probe is None
                else threads_for(self.probe.other_cores(), available_cores())
            )
            if n != torch.get_num_threads():
                torch.set_num_threads(n)
        return torch.get_num_threads()

    def __exit__(self, *exc) -> None:
        _OUTER.reset(self.token)
        torch.set_num_threads(self.previous)


@contextmanager
def torch_threads(n: int | str | None) -> Iterator[int]:
    """Run the block with ``n`` torch threads (an int, ``"auto"``: the cores other programs leave
    free, chosen once at the start; ``None`` or 0: torch's setting) and restore the previous number
    after it (also when the block raises). Yields the number in effect."""
    with ThreadGovernor(n) as gov:
        yield torch.get_num_threads() if gov.fixed is None else gov.fixed


@contextmanager
def one_thread() -> Iterator[None]:
    """Run the block on one torch thread (MKL's too) and restore the number after it; nothing is
    switched when torch already runs one. For an operation whose bits depend on the thread count,
    such as MKL's matrix products under a pinned code path (the app's ``MKL_CBWR``), which split
    their columns between threads and give other last bits on two threads than on one. Not
    :func:`torch_threads` ``(1)``: this sits in hot paths (every ProMP product), so it skips the
    governor's bookkeeping and does nothing at all on one thread."""
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
