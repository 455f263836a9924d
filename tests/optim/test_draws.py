"""Noise drawn ahead in a background thread (protorch.optim.draws): the same numbers, the same
generator state, a wrong guess undone, a failed update restarted, RWPO left alone."""

from __future__ import annotations

import pytest
import torch

from protorch import PRO, RWPO
from protorch.optim import CEM, EPRO, RWR
from protorch.optim import pro as pro_module
from protorch.optim.draws import NormalDraws

F64 = torch.float64


def cost(w):  # (B, S, N) -> (B, S, 3): objectives that read different weights
    return torch.stack(
        [(w[..., :3] - 1).pow(2).sum(-1), w[..., 3:6].abs().sum(-1), w.sum(-1).abs()], -1
    )


def start(batch: int = 6, n: int = 8):
    g = torch.Generator().manual_seed(0)
    return torch.randn(batch, n, generator=g, dtype=F64), torch.rand(
        batch, n, generator=g, dtype=F64
    )


@pytest.mark.parametrize(
    "cls, kw",
    [
        (PRO, dict(beta=5.0, relevance_samples=30, num_samples=20)),  # two shapes per iteration
        (
            PRO,
            dict(beta=5.0, relevance_samples=20, num_samples=20, relevance_every=3),
        ),  # the plan changes
        (RWR, dict(beta=5.0, num_samples=20)),
        (CEM, dict(num_samples=20)),
        (EPRO, dict(num_samples=20)),
    ],
)
def test_drawing_ahead_changes_no_number(cls, kw):
    results = []
    for ahead in (False, True):
        opt = cls(*start(), seed=3, max_iter=12, **kw)
        if ahead:
            assert opt.draw_ahead() is True
        res = opt.minimize(cost)
        results.append((res, opt.generator.get_state()))
    (a, sa), (b, sb) = results
    assert (
        torch.equal(a.mean, b.mean)
        and torch.equal(a.var, b.var)
        and torch.equal(a.converged, b.converged)
    )
    assert a.iterations == b.iterations and torch.equal(
        sa, sb
    )  # the draw made ahead for no ask is undone


def test_a_wrong_guess_is_undone():
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    plain, ahead = NormalDraws(g1), NormalDraws(g2)
    ahead.start_ahead()
    for shape in [
        (3, 4),
        (3, 4),
        (2, 7),
        (3, 4),
        (5,),
    ]:  # the guess (the last shape) is wrong twice
        assert torch.equal(plain.draw(shape, F64, "cpu"), ahead.draw(shape, F64, "cpu"))
    assert torch.equal(ahead.get_state(), g1.get_state())
    ahead.cancel()
    assert torch.equal(g2.get_state(), g1.get_state())


def test_a_failed_update_restarts_the_iteration_with_the_same_draw(monkeypatch):
    opt = PRO(*start(), beta=5.0, num_samples=10, relevance_samples=10, seed=3)
    assert opt.draw_ahead()
    ref = PRO(*start(), beta=5.0, num_samples=10, relevance_samples=10, seed=3)
    real, calls = pro_module.pro_update, []

    def failing_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("boom")
        return real(*args, **kwargs)

    monkeypatch.setattr(pro_module, "pro_update", failing_once)
    first = opt.ask()
    opt.tell(cost(first))
    opt.tell(cost(opt.ask()))
    with pytest.raises(RuntimeError, match="boom"):
        opt.tell(cost(opt.ask()))
    assert torch.equal(opt.ask(), first)  # back at the start of the iteration: the same draw again
    assert torch.equal(ref.ask(), first)


def test_rwpo_draws_its_own_numbers_and_does_not_draw_ahead():
    opt = RWPO(*start(n=6), beta=5.0, num_objectives=3, num_basis=3, seed=0)
    assert opt.draw_ahead() is False and not opt.draws.ahead
