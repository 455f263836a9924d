"""``planner="process"`` (protorch.policy.process_planner): the planner in a forked child, the
inputs and plans in shared memory: its plans are the threaded planner's, it keeps up with a
paced loop, follows a switch, and its child ends with close()."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from protorch.policy.process_planner import _read, _write
from tests.control.test_policy import toy_policy
from tests.policy.test_two_rate import walk

F64 = torch.float64


def test_the_sequence_lock_refuses_a_copy_taken_while_written():
    arr = np.zeros(4)
    _write(arr, np.array([1.0, 2.0, 3.0]))
    assert arr[0] == 2 and _read(arr).tolist() == [2.0, 1.0, 2.0, 3.0]
    arr[0] += 1  # a writer half way through
    assert _read(arr) is None


def test_the_process_planner_gives_the_threaded_planners_reference():
    """At a fixed environment (one plan per decision, the same class) the reference of the two
    planners is the same to 1e-12 at every tick once the child's first plan is in."""
    env = torch.tensor([0.45, 0.55], dtype=F64)
    q0 = torch.tensor([0.1, -0.2], dtype=F64)
    refs = []
    for planner in ("thread", "process"):
        pol = toy_policy(nearest_k=8, planner=planner, plan_period=2e-3)
        pol.reset(env, q0)
        refs.append([pol.reference(env, i * 1e-3, q0 if i == 0 else None) for i in range(50)])
        pol.close()
    for a, b in zip(*refs):
        assert a.label == b.label
        for x, y in zip(a[:3], b[:3]):
            torch.testing.assert_close(y, x, rtol=0, atol=1e-12)


def test_the_process_planner_follows_a_paced_loop_and_ends_with_close():
    pol = toy_policy(nearest_k=8, planner="process", plan_period=2e-3)
    envs = walk(400)
    pol.reset(envs[0])
    labels, ages = set(), []
    due = time.perf_counter()
    for i in range(400):
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        due += 1e-3
        r = pol.reference(envs[i], i * 1e-3)
        labels.add(r.label)
        ages.append(i * 1e-3 - r.plan_t)
    assert pol._planner.plans >= 10  # the child planned while the loop ran
    assert labels == {0, 1} and min(ages) >= 0.0
    proc = pol._planner._proc
    pol.close()
    assert not proc.is_alive()


def test_the_process_planner_is_refused_without_a_task():
    pol = toy_policy(nearest_k=8)
    with pytest.raises(ValueError, match="planner='process' on a map with several classes"):
        type(pol)(pol._P, pol.env_map, pol.task_name, planner="process")
