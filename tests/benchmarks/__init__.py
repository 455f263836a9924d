"""Tests of the on-demand benchmarks at tiny budgets."""

from __future__ import annotations

import importlib.util
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT / "benchmarks") not in sys.path:  # the scripts' own imports (_timing, configs)
    sys.path.append(str(ROOT / "benchmarks"))


@contextmanager
def benchmark_module(
    filename: str, name: str, setup: Callable | None = None, also: tuple[str, ...] = ()
) -> Iterator:
    """``benchmarks/<filename>`` imported as module ``name`` (``main()`` is not called: it would
    set this process's threads), with ``setup(module)`` run on it; the environment variables the
    module sets for itself (``OMP_NUM_THREADS`` & co.) are restored for later tests'
    subprocesses, and ``name`` (and the modules in ``also``) leave ``sys.modules`` afterwards."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / filename)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up there
    env = dict(os.environ)
    try:
        spec.loader.exec_module(mod)
        if setup is not None:
            setup(mod)
    finally:
        os.environ.clear()
        os.environ.update(env)
    try:
        yield mod
    finally:
        for n in (name, *also):
            sys.modules.pop(n, None)
