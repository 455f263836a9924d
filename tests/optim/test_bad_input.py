"""Settings and costs that can only be judged against the costs: ``tell`` refuses them the first
time and every time, without consuming the pending ask or changing any state, and a failure
inside an update leaves the optimiser at the start of its iteration."""

from __future__ import annotations

import math

import pytest
import torch

import protorch.optim.pro as pro_module
from protorch import PRO, RWR
from protorch.optim.cem import CEM

F64 = torch.float64


def _state(opt):
    return (
        opt.mean.clone(),
        opt.var.clone(),
        opt.iteration,
        opt.num_objectives,
        opt.generator.get_state().clone(),
    )


def _same(a, b):
    for x, y in zip(a, b):
        assert torch.equal(x, y) if isinstance(x, torch.Tensor) else x == y


@pytest.mark.parametrize("cls", [RWR, CEM])
def test_objective_weights_of_the_wrong_length_fail_every_time_without_consuming(cls):
    kw = {} if cls is CEM else {"beta": 5.0}
    opt = cls(
        torch.zeros(3, dtype=F64),
        torch.ones(3, dtype=F64),
        objective_weights=[1, 1, 1],
        num_samples=10,
        seed=0,
        **kw,
    )
    w = opt.ask()
    before = _state(opt)
    for _ in range(3):
        with pytest.raises(ValueError, match="objective_weights"):
            opt.tell(torch.ones(10, 2, dtype=F64))
        _same(_state(opt), before)
    # the ask is still pending: right-sized costs are accepted and the iteration ends with an update
    opt.tell((w**2).sum(-1, keepdim=True).expand(10, 3).clone())
    assert opt.iteration == 1 and not torch.equal(opt.mean, before[0])


def test_costs_that_overflow_float32_are_refused_before_anything_changes():
    opt = PRO(
        torch.zeros(3),
        torch.ones(3),
        beta=5.0,
        num_samples=10,
        relevance_samples=10,
        seed=0,
        dtype=torch.float32,
    )
    w = opt.ask()
    before = _state(opt)
    for _ in range(2):
        with pytest.raises(ValueError, match="float32"):
            opt.tell(torch.full((10, 1), 1e39, dtype=F64))
        _same(_state(opt), before)
    opt.tell(w.sum(-1, keepdim=True))  # then the run goes on


def test_huge_float32_costs_give_a_finite_relevance():
    opt = PRO(
        torch.zeros(3),
        torch.ones(3),
        beta=5.0,
        num_samples=10,
        relevance_samples=20,
        seed=0,
        dtype=torch.float32,
    )
    w = opt.ask()
    opt.tell(1e37 * (2 + 100 * w[:, :1]))  # finite in float32, but its square is not
    assert bool(torch.isfinite(opt.relevance).all()) and float(opt.relevance.max()) == 1.0


@pytest.mark.parametrize("value", [math.inf, math.nan, 0.0, -1e-5])
def test_relevance_var_must_be_finite_and_positive(value):
    with pytest.raises(ValueError, match="relevance_var"):
        PRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), beta=1.0, relevance_var=value)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"num_samples": 2.9}, "num_samples"),
        ({"max_iter": 3.5}, "max_iter"),
        ({"tol": math.nan}, "tol"),
        ({"noise_floor": math.nan}, "noise_floor"),
        ({"relevance_samples": 10.5}, "relevance_samples"),
        ({"window": math.nan}, "window"),
    ],
)
def test_fractional_or_nan_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        PRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), beta=1.0, **kw)


def test_a_failure_inside_an_update_restarts_the_iteration(monkeypatch):
    """Whatever raises inside ``tell`` (here: the update itself, once), the optimiser is back at
    the start of its iteration: nothing half-applied, and the next ask repeats the same draw."""

    def make():
        return PRO(
            torch.zeros(2, 3, dtype=F64),
            torch.ones(2, 3, dtype=F64),
            beta=5.0,
            num_samples=10,
            relevance_samples=10,
            seed=3,
        )

    def cost(w):
        return torch.stack([(w[..., 0] - 1) ** 2, w[..., 2].abs()], -1)

    ref = make()
    first = ref.ask()
    ref.tell(cost(first))
    second = ref.ask()
    opt = make()
    before = _state(opt)
    real, calls = pro_module.pro_update, []

    def failing_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:  # the second objective's update
            raise RuntimeError("boom")
        return real(*args, **kwargs)

    monkeypatch.setattr(pro_module, "pro_update", failing_once)
    opt.tell(cost(opt.ask()))
    opt.tell(cost(opt.ask()))
    with pytest.raises(RuntimeError, match="boom"):
        opt.tell(cost(opt.ask()))
    _same(_state(opt)[:3], before[:3])
    assert torch.equal(opt.generator.get_state(), before[4])
    again = opt.ask()
    assert torch.equal(again, first)  # the iteration starts over
    opt.tell(cost(again))
    assert torch.equal(opt.ask(), second)
