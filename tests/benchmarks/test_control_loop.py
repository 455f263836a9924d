"""benchmarks/control_loop.py's count of flickering class switches (a switch undone within a few
decisions), on labels written by hand."""

from __future__ import annotations

import torch

from tests.benchmarks import benchmark_module


def test_switches_undone_within_three_decisions_are_counted_per_episode():
    labels = torch.tensor(
        [
            [0, 0, 1, 0, 0, 0, 0, 0],  # 0 -> 1 -> 0 one decision apart: one undone
            [0, 0, 1, 1, 1, 1, 0, 0],  # back after 4 decisions: not a flicker
            [1, 0, 1, 0, 1, 1, 1, 1],  # four switches, each undone at the next decision: three
            [1, 1, 1, 1, 1, 1, 1, 1],  # no switch
        ]
    )
    with benchmark_module("control_loop.py", "_control_loop") as bench:
        assert bench.reversed_switches(labels) == (4, 2)
        assert bench.reversed_switches(labels, within=4) == (5, 3)


def test_each_timed_call_is_sorted_by_what_it_did():
    """time_calls' kinds: one decision per ``decision_dt`` slot of the motion, the calls that
    solved a new neighbour set among the rest, every call once."""
    from tests.control.test_policy import toy_policy

    policy = toy_policy(nearest_k=8)
    with benchmark_module("control_loop.py", "_control_loop") as bench:
        envs = bench.environments(policy, 300, "moving")  # 0.3 s of a 2 s motion at 1 kHz
        kinds: list[str] = []
        ts, cpu, misses = bench.time_calls(policy, envs, kinds)
    assert len(kinds) == len(ts) == len(cpu) == 300
    assert (
        sum(k.startswith("decision") for k in kinds) == 15
    )  # t = 0 .. 0.299 s, a decision every 20 ms
    solved = sum(k.endswith("solve") for k in kinds)
    assert 0 < solved <= misses
    assert set(kinds) <= {"light", "solve", "decision", "decision + solve"}


def test_the_pieces_are_timed_and_the_timers_removed(capsys):
    """time_pieces wraps the decision's pieces in timers for one walk and puts them back."""
    import protorch.control.arm_choice as ac
    from protorch.policy.means import ClassMeans
    from protorch.policy.policy import Policy
    from tests.control.test_policy import toy_policy

    before = (ClassMeans.__call__, Policy._scores, ac.rest_plan)
    policy = toy_policy(nearest_k=8)
    with benchmark_module("control_loop.py", "_control_loop") as bench:
        bench.time_pieces(policy, bench.environments(policy, 100, "moving"))
    out = capsys.readouterr().out
    assert "the scores" in out and " 5 calls" in out  # a decision every 20 ms of the 0.1 s walk
    assert (ClassMeans.__call__, Policy._scores, ac.rest_plan) == before


def test_collections_are_counted_only_within_the_timed_calls():
    """The garbage collector's collections are recorded while a call is timed, per generation."""
    import gc

    with benchmark_module("control_loop.py", "_control_loop") as bench:
        rec = bench.Collections()
        rec.start()
        try:
            gc.collect()  # not timed: not counted
            rec.on = True
            gc.collect()
            gc.collect(0)
            rec.on = False
            gc.collect()
            assert [g for g, _ in rec.seen] == [2, 0]
            assert rec.summary().startswith("generation 0: 1 (longest ")
            assert (
                "generation 1: 0;" in rec.summary() and "generation 2: 1 (longest " in rec.summary()
            )
        finally:
            rec.stop()
        assert rec not in gc.callbacks


def test_the_soak_reports_after_each_walk(capsys):
    """soak: a line before, then one after each walk of ``chunk`` calls, the last one short."""
    from tests.control.test_policy import toy_policy

    policy = toy_policy(nearest_k=8)
    with benchmark_module("control_loop.py", "_control_loop") as bench:
        bench.soak(policy, 250, chunk=100)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("soak: 250 calls; before: ")
    assert [line.split(":")[0].strip() for line in lines[1:]] == [
        f"after {n} calls" for n in (100, 200, 250)
    ]
    assert all("MB resident" in line and "objects tracked" in line for line in lines)
