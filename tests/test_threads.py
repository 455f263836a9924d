"""``torch_threads``: the number inside the block, the old one restored after it (also on error);
a run's metrics do not depend on the number."""

from __future__ import annotations

import pytest
import torch

from protorch.threads import torch_threads
from tests.small_runs import SMALL, small_run


def test_sets_and_restores_threads_even_when_the_block_raises():
    before = torch.get_num_threads()
    with torch_threads(1) as n:
        assert n == 1 and torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError):
        with torch_threads(1):
            raise RuntimeError("boom")
    assert torch.get_num_threads() == before


def test_none_leaves_torch_alone_and_bad_values_are_refused():
    before = torch.get_num_threads()
    with torch_threads(None) as n:
        assert n == before == torch.get_num_threads()
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            with torch_threads(bad):
                pass
    assert torch.get_num_threads() == before


def test_the_free_cores_rule():
    from protorch.threads import threads_for

    assert threads_for(0.0, 2) == 2 and threads_for(0.2, 2) == 2  # idle (a little noise): every core
    assert threads_for(0.5, 2) == 1 and threads_for(1.0, 2) == 1  # one competitor on 2 cores: one thread
    assert threads_for(5.0, 2) == 1  # never fewer than one
    assert threads_for(1.0, 8) == 7 and threads_for(0.0, 1) == 1


def test_auto_inside_a_fixed_setting_keeps_the_callers_number():
    from protorch.threads import ThreadGovernor

    before = torch.get_num_threads()
    with torch_threads(1):
        with ThreadGovernor("auto") as inner:  # the loop's default inside the app's threads=1
            assert inner.fixed == 1 and inner.step() == 1 and torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_the_probe_counts_the_machine_busy_time_minus_its_own(monkeypatch):
    import os
    from types import SimpleNamespace

    import protorch.threads as th

    hz, ncpu = os.sysconf("SC_CLK_TCK"), os.cpu_count() or 1
    machine = iter([(0, 0), (3 * hz // 2, ncpu * hz)])  # 1 s of wall time: 1.5 cores busy in all
    ours = iter([0.0, 0.5])  # of which this process used 0.5 core-seconds
    monkeypatch.setattr(th, "_machine_jiffies", lambda: next(machine))
    monkeypatch.setattr(th.os, "times", lambda: SimpleNamespace(user=next(ours), system=0.0))
    assert th.LoadProbe().other_cores() == pytest.approx(1.0)


@pytest.mark.slow
@pytest.mark.skipif(not __import__("os").path.exists("/proc/stat"), reason="the load probe reads /proc/stat")
def test_the_probe_sees_another_busy_process():
    import subprocess
    import sys
    import time

    from protorch.threads import LoadProbe

    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.2:  # the competitor starts; this process's work is its own
            pass
        probe = LoadProbe()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.5:
            pass
        other = probe.other_cores()
    finally:
        spin.kill()
        spin.wait()
    assert other > 0.6, other  # the spinner's core (any further load only adds to it)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SMALL))
def test_a_runs_metrics_are_the_same_at_one_and_two_threads(name):
    one, two = small_run(name, 1), small_run(name, 2)
    assert any(k.startswith("checkpoint:") for k in one)
    assert one == two  # every metric, and the loops' data sets bit for bit


def test_the_core_budget_and_the_threads_beside_workers():
    from protorch.threads import available_cores, beside_workers, core_budget

    with torch_threads(1):
        assert core_budget() == 1 and beside_workers(1) == 1  # one core: never fewer than one thread
    with torch_threads(3):
        assert core_budget() == 3 and beside_workers(1) == 2
    with torch_threads("auto"):
        assert core_budget() == available_cores() and beside_workers(1) == "auto"  # auto measures the workers
    assert core_budget() == available_cores()  # no setting: the available cores
