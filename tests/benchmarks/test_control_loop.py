"""benchmarks/control_loop.py's count of flickering class switches (a switch undone within a few
decisions), on labels written by hand."""

from __future__ import annotations

import torch

from tests.benchmarks import benchmark_module


def test_switches_undone_within_three_decisions_are_counted_per_episode():
    labels = torch.tensor([
        [0, 0, 1, 0, 0, 0, 0, 0],  # 0 -> 1 -> 0 one decision apart: one undone
        [0, 0, 1, 1, 1, 1, 0, 0],  # back after 4 decisions: not a flicker
        [1, 0, 1, 0, 1, 1, 1, 1],  # four switches, each undone at the next decision: three
        [1, 1, 1, 1, 1, 1, 1, 1],  # no switch
    ])
    with benchmark_module("control_loop.py", "_control_loop") as bench:
        assert bench.reversed_switches(labels) == (4, 2)
        assert bench.reversed_switches(labels, within=4) == (5, 3)
