"""benchmarks/optim.py at a tiny budget: the loop-style evaluation it times gives PRO the same
numbers as the objective as written (so both rows time the same optimisation), and its batching
timer runs."""

from __future__ import annotations

import pytest
import torch

from protorch import PRO

from . import benchmark_module


@pytest.fixture(scope="module")
def bench():
    with benchmark_module("optim.py", "optim_bench") as mod:
        yield mod


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_asked_objective_gives_pro_the_numbers_of_the_full_one(bench, dtype):
    task, promp, full = bench.window_problem(dtype=dtype)
    runs = []
    for asked in (False, True):
        opt = PRO(
            promp.mean.expand(5, -1).clone(),
            promp.var.expand(5, -1).clone(),
            beta=20.0,
            num_samples=20,
            relevance_samples=20,
            max_iter=3,
            tol=0.0,
            seed=0,
        )
        f = bench.asked_objective(task, promp, opt) if asked else full
        read = []
        while not opt.stop():
            w = opt.ask()  # (5, S, N)
            c = f(w)  # (5, S, 3)
            read.append(c if opt.asked_objective is None else c[..., opt.asked_objective])
            opt.tell(c)
        runs.append((opt.result(), read))
    (a, read_a), (b, read_b) = runs
    assert (
        len(read_a) == len(read_b) == 3 * 4
    )  # a relevance ask and three objective asks per iteration
    assert all(torch.equal(x, y) for x, y in zip(read_a, read_b))
    assert torch.equal(a.mean, b.mean) and torch.equal(a.var, b.var)


def test_batch_timer_runs(bench):
    for asked in (False, True):
        total, objective = bench.bench_batch(2, 1, "cpu", rows=1, dtype=torch.float32, asked=asked)
        assert total > 0 and 0 < objective <= total
