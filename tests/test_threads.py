"""``torch_threads``: the number inside the block, the old one restored after it (also on error)."""

from __future__ import annotations

import pytest
import torch

from protorch.threads import torch_threads


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


@pytest.mark.skipif(not __import__("os").path.exists("/proc/stat"), reason="the load probe reads /proc/stat")
def test_the_probe_sees_another_busy_process_and_not_its_own_work():
    import subprocess
    import sys
    import time

    from protorch.threads import LoadProbe

    def work(seconds):  # this process's own work, which is never "other" load
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            pass

    probe = LoadProbe()
    work(0.3)
    own = probe.other_cores()
    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        work(0.2)  # the competitor starts
        probe.other_cores()
        work(0.5)  # both busy: the competitor is the other load
        other = probe.other_cores()
    finally:
        spin.kill()
        spin.wait()
    assert other > own + 0.5 and other > 0.6, (own, other)
