"""One contract suite for every optimiser: ask / tell / stop / result over B problems at once.

Each test runs for every optimiser registered in ``protorch.optim.OPTIMIZERS`` (PRO, RWR, RWPO with
a
tiny relevance-learning budget, the peers CEM and CMA-ES with pycma behind the same contract, and
any
optimiser registered later, with its default settings).
"""

import pytest
import torch

from protorch import PRO, RWPO, RWR, OptimizeResult
from protorch.optim import CEM, CMAES, OPTIMIZERS

F64 = torch.float64

SMALL = {
    PRO: {"relevance_samples": 50},
    RWR: {},
    RWPO: {"relevance_iters": 3, "theta_samples": 8, "trajectory_samples": 4},
    CEM: {
        "extra_var": 1e-2
    },  # the noisy CEM: plain CEM collapses within the 12 iterations a test watches
    CMAES: {
        "pycma_stop": False
    },  # the contract's stopping rule alone (test_peers.py checks pycma's)
}
RANK_BASED = (CEM, CMAES)  # no reward temperature: only the order of the costs matters
# a registered optimiser not listed in SMALL runs with its defaults; RWPO-like ones needing more
# arguments add them to SMALL


@pytest.fixture(params=sorted(OPTIMIZERS), ids=str)
def make(request):
    """``make(mean, var=1.0, **kw)`` builds the optimiser under test with small settings."""
    cls = OPTIMIZERS[request.param]  # every registered optimiser, a new one included

    def build(mean, var=1.0, **kw):
        if cls in RANK_BASED:
            kw.pop("beta", None)
        else:
            kw.setdefault("beta", 1.0)
        kw.setdefault("num_samples", 20)
        kw.setdefault("num_objectives", 2)
        kw.setdefault("seed", 0)
        return cls(mean, torch.as_tensor(var, dtype=F64), **{**SMALL.get(cls, {}), **kw})

    build.cls = cls
    return build


def two_objectives(w):
    """``(..., S, N) -> (..., S, 2)``: squared distance of w_0 to 1 and of the rest to -1."""
    return torch.stack([(w[..., 0] - 1) ** 2, (w[..., 1:] + 1).pow(2).sum(-1)], -1)


def one_iteration(opt, fn):
    """Ask/tell until the iteration counter moves; return the shapes asked."""
    start, shapes = opt.iteration, []
    while opt.iteration == start:
        w = opt.ask()
        shapes.append(tuple(w.shape))
        opt.tell(fn(w))
    return shapes


# ------------------------------------------------------------------------- ask / tell
def test_ask_tell_unbatched_shapes(make):
    opt = make(torch.zeros(4, dtype=F64))
    shapes = one_iteration(opt, two_objectives)
    assert all(len(s) == 2 and s[1] == 4 for s in shapes)
    assert (20, 4) in shapes  # the update samples
    assert opt.iteration == 1


def test_ask_tell_batched_shapes(make):
    opt = make(torch.zeros(3, 4, dtype=F64))
    shapes = one_iteration(opt, two_objectives)
    assert all(len(s) == 3 and s[0] == 3 and s[2] == 4 for s in shapes)
    assert (3, 20, 4) in shapes


def test_single_objective_accepts_costs_without_objective_dim(make):
    opt = make(torch.zeros(3, dtype=F64), num_objectives=1)
    for _ in range(2):
        one_iteration(opt, lambda w: (w - 0.5).pow(2).sum(-1))  # (S,) unbatched
    batched = make(torch.zeros(2, 3, dtype=F64), num_objectives=1)
    one_iteration(batched, lambda w: (w - 0.5).pow(2).sum(-1))  # (B, S)
    assert opt.iteration == 2 and batched.iteration == 1


def test_ask_twice_raises(make):
    opt = make(torch.zeros(2, 4, dtype=F64))
    opt.ask()
    with pytest.raises(RuntimeError, match=r"ask\(\) called twice"):
        opt.ask()


def test_tell_without_ask_raises(make):
    opt = make(torch.zeros(4, dtype=F64))
    with pytest.raises(RuntimeError, match=r"tell\(\) called without a pending ask"):
        opt.tell(torch.zeros(20, 2))
    w = opt.ask()
    opt.tell(two_objectives(w))
    with pytest.raises(RuntimeError, match="without a pending ask"):
        opt.tell(two_objectives(w))


def test_wrong_costs_shape_raises_and_keeps_the_pending_ask(make):
    opt = make(torch.zeros(3, 4, dtype=F64))
    w = opt.ask()
    good = two_objectives(w)
    for bad in (good[:, :-1], good[:2], good[..., None], good[0, 0]):
        with pytest.raises(ValueError, match=r"costs must be \(B, S, O\)"):
            opt.tell(bad)
    with pytest.raises(ValueError, match="expected 2 objective"):
        opt.tell(torch.cat([good, good], -1))
    opt.tell(good)  # the ask is still pending and can be answered


def test_unbatched_wrong_costs_shape_raises(make):
    opt = make(torch.zeros(4, dtype=F64))
    w = opt.ask()
    with pytest.raises(ValueError, match=r"costs must be \(B, S, O\)"):
        opt.tell(two_objectives(w)[:-1])


@pytest.mark.parametrize(
    "bad, word", [(float("nan"), "NaN"), (float("inf"), "inf"), (-float("inf"), "inf")]
)
def test_non_finite_costs_raise(make, bad, word):
    opt = make(torch.zeros(2, 4, dtype=F64))
    costs = two_objectives(opt.ask())
    costs[1, 3, 0] = bad
    with pytest.raises(ValueError, match=f"costs contains {word}"):
        opt.tell(costs)
    assert bool(torch.isfinite(opt.mean).all())


# -------------------------------------------------------------------- construction
@pytest.mark.parametrize("beta", [0.0, -1.0, float("nan"), float("inf"), torch.tensor([1.0, -1.0])])
def test_bad_beta_raises(make, beta):
    if make.cls in RANK_BASED:
        with pytest.raises(TypeError, match="rank-based and takes no beta"):
            make.cls(torch.zeros(2, 4, dtype=F64), torch.ones(4, dtype=F64), beta=beta)
        return
    with pytest.raises(ValueError, match="beta must be finite and > 0"):
        make(torch.zeros(2, 4, dtype=F64), beta=beta)


def test_per_problem_beta(make):
    if make.cls in RANK_BASED:
        # no temperature to set per problem: scaling each problem's costs by its own positive
        # factor (what a per-problem beta would do to exp(-beta c)) leaves the run unchanged
        scale = torch.tensor([0.5, 1.0, 20.0], dtype=F64)[:, None, None]
        a = make(torch.zeros(3, 4, dtype=F64), max_iter=4, tol=0.0).minimize(two_objectives)
        b = make(torch.zeros(3, 4, dtype=F64), max_iter=4, tol=0.0).minimize(
            lambda w: scale * two_objectives(w)
        )
        assert torch.equal(a.mean, b.mean) and torch.equal(a.var, b.var)
        return
    opt = make(torch.zeros(3, 4, dtype=F64), beta=torch.tensor([0.5, 1.0, 2.0]))
    assert opt.beta.tolist() == [0.5, 1.0, 2.0]
    one_iteration(opt, two_objectives)
    with pytest.raises(ValueError, match=r"beta must be a float or \(3,\)"):
        make(torch.zeros(3, 4, dtype=F64), beta=torch.tensor([1.0, 2.0]))


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"mean": torch.zeros(2, 3, 4, dtype=F64)}, r"mean must be \(N,\) or \(B, N\)"),
        ({"mean": torch.tensor([0.0, float("nan")], dtype=F64)}, "mean contains NaN"),
        ({"var": -1.0}, "var must be >= 0"),
        ({"var": [1.0, float("inf"), 1.0, 1.0]}, "var contains inf"),
        ({"var": torch.ones(3)}, "does not match mean"),
        ({"num_samples": 1}, "num_samples must be >= 2"),
        ({"max_iter": 0}, "max_iter must be >= 1"),
        ({"tol": -1.0}, "need tol >= 0"),
        ({"window": 0}, "window >= 1"),
    ],
)
def test_bad_construction_raises(make, kw, message):
    kw = dict(kw)
    mean = kw.pop("mean", torch.zeros(4, dtype=F64))
    with pytest.raises(ValueError, match=message):
        make(mean, **kw)


def test_var_broadcasts_against_mean(make):
    opt = make(torch.zeros(3, 4, dtype=F64), var=torch.tensor([1.0, 2.0, 3.0, 4.0]))
    assert opt.var.shape == (3, 4)
    assert opt.var[2].tolist() == [1.0, 2.0, 3.0, 4.0]


# ------------------------------------------------------------------- stop / converge
def test_stops_after_max_iter(make):
    opt = make(torch.zeros(2, 4, dtype=F64), max_iter=4, tol=0.0)
    res = opt.minimize(two_objectives)
    assert res.iterations == opt.iteration == 4
    assert opt.stop() and opt.stop_reason() == "max_iter"
    assert not bool(res.converged.any())
    with pytest.raises(RuntimeError, match=r"stopped \(max_iter\)"):
        opt.ask()


def test_stop_is_false_mid_iteration(make):
    opt = make(torch.zeros(4, dtype=F64), max_iter=1, tol=0.0)
    assert not opt.stop()
    opt.ask()
    assert not opt.stop()  # a pending ask must be answered


def test_constant_objective_converges_after_window_iterations(make):
    window = 3
    opt = make(torch.zeros(2, 4, dtype=F64), max_iter=50, window=window, tol=1e-3)
    res = opt.minimize(lambda w: torch.ones(*w.shape[:-1], 2, dtype=w.dtype))
    assert res.iterations == window
    assert bool(res.converged.all()) and opt.stop_reason() == "converged"


def test_tol_zero_never_converges(make):
    opt = make(torch.zeros(4, dtype=F64), max_iter=6, window=2, tol=0.0)
    res = opt.minimize(lambda w: torch.ones(*w.shape[:-1], 2, dtype=w.dtype))
    assert res.iterations == 6 and not bool(res.converged)


def test_mark_converged_freezes_problems_from_outside(make):
    opt = make(torch.zeros(3, 4, dtype=F64), max_iter=6, tol=0.0)
    opt.mark_converged(torch.tensor([True, False, False]))
    assert opt.active.tolist() == [False, True, True]
    res = opt.minimize(two_objectives)
    assert res.iterations == 6 and res.converged.tolist() == [True, False, False]
    assert torch.equal(res.mean[0], torch.zeros(4, dtype=F64))  # never moved
    assert not torch.equal(res.mean[1], torch.zeros(4, dtype=F64))
    opt = make(torch.zeros(2, 4, dtype=F64), max_iter=6, tol=0.0)
    opt.mark_converged(torch.tensor([True, True]))
    assert opt.stop() and opt.stop_reason() == "converged"
    unbatched = make(torch.zeros(4, dtype=F64))
    unbatched.mark_converged(True)
    assert unbatched.stop()
    with pytest.raises(ValueError, match="bool"):
        opt.mark_converged(torch.tensor([1, 0]))
    with pytest.raises(ValueError, match=r"\(2,\)"):
        opt.mark_converged(torch.tensor([True, False, True]))


def test_costs_of_inactive_problems_are_never_read(make):
    """The loop evaluates only ``opt.active`` problems: any finite cost for the others is fine."""
    runs = []
    for filler in (0.0, 1e6):
        opt = make(torch.zeros(3, 4, dtype=F64), max_iter=5, tol=0.0)
        opt.mark_converged(torch.tensor([False, True, False]))

        def fn(w, opt=opt, filler=filler):
            c = two_objectives(w)
            c[~opt.active] = filler
            return c

        runs.append(opt.minimize(fn))
    assert torch.equal(runs[0].mean, runs[1].mean) and torch.equal(runs[0].var, runs[1].var)


def test_rollouts_count_the_samples_told_while_a_problem_was_active(make):
    opt = make(torch.zeros(3, 4, dtype=F64), max_iter=4, tol=0.0)
    opt.mark_converged(torch.tensor([False, True, False]))
    told = torch.zeros(3, dtype=torch.long)
    while not opt.stop():
        w = opt.ask()  # (B, S, N)
        told += opt.active.long() * w.shape[1]
        opt.tell(two_objectives(w))
    res = opt.result()
    assert (
        res.rollouts.tolist() == told.tolist() and res.rollouts[1] == 0 and res.rollouts[0] >= 4 * 2
    )
    unbatched = make(torch.zeros(4, dtype=F64), max_iter=2, tol=0.0)
    assert int(unbatched.minimize(two_objectives).rollouts) > 0


def test_converged_problems_stop_moving(make):
    # problem 0 has a constant cost (converges after `window` iterations), problem 1 does not
    window = 3

    def fn(w):
        c = two_objectives(w)
        c[0] = 1.0
        return c

    opt = make(torch.zeros(2, 4, dtype=F64), max_iter=12, window=window, tol=1e-3, beta=1.0)
    res = opt.minimize(fn)
    assert res.iterations == 12
    assert res.converged.tolist() == [True, False]
    frozen = res.history["mean"][window - 1 :, 0]  # (I - window + 1, N)
    assert torch.equal(frozen, frozen[:1].expand_as(frozen))
    assert torch.equal(
        res.history["var"][window - 1 :, 0],
        res.history["var"][window - 1 : window, 0].expand_as(frozen),
    )
    moving = res.history["mean"][window - 1 :, 1]
    assert not torch.equal(moving, moving[:1].expand_as(moving))


def test_batch_of_problems_with_different_targets_each_solved(make):
    targets = torch.tensor([[1.0, -1.0, 0.5], [-2.0, 0.0, 2.0], [0.3, 0.3, -0.3]], dtype=F64)

    def quad(w):  # (B, S, N) -> (B, S, 1): each problem has its own target
        return (w - targets[:, None]).pow(2).sum(-1, keepdim=True)

    opt = make(
        torch.zeros(3, 3, dtype=F64), beta=1.0, num_samples=100, max_iter=60, num_objectives=1
    )
    res = opt.minimize(quad)
    err = (res.mean[:, None] - targets[None]).norm(dim=-1)  # (B, B): problem i vs target j
    assert bool((err.diagonal() < 0.4).all()), err.diagonal()
    assert torch.equal(err.argmin(1), torch.arange(3))


def test_problems_in_a_batch_are_independent(make):
    # same seed, same costs for problem 0, very different costs for problem 1: problem 0's run
    # must be bit-for-bit the same, so no problem leaks into another
    def fn_a(w):
        return two_objectives(w)

    def fn_b(w):
        c = two_objectives(w)
        c[1] = 100.0 * (w[1, :, :2] - 3).abs()
        return c

    a = make(torch.zeros(2, 4, dtype=F64), max_iter=5, tol=0.0).minimize(fn_a)
    b = make(torch.zeros(2, 4, dtype=F64), max_iter=5, tol=0.0).minimize(fn_b)
    for k in a.history:
        assert torch.equal(a.history[k][:, 0], b.history[k][:, 0]), k
        assert not torch.equal(a.history[k][:, 1], b.history[k][:, 1]), k


def test_unbatched_equals_a_batch_of_one(make):
    a = make(torch.zeros(4, dtype=F64), max_iter=4, tol=0.0).minimize(two_objectives)
    b = make(torch.zeros(1, 4, dtype=F64), max_iter=4, tol=0.0).minimize(two_objectives)
    assert torch.equal(a.mean, b.mean[0]) and torch.equal(a.var, b.var[0])
    for k in a.history:
        assert torch.equal(a.history[k], b.history[k][:, 0]), k


def test_seeded_runs_are_reproducible(make):
    a = make(torch.zeros(2, 4, dtype=F64), seed=7, max_iter=5, tol=0.0).minimize(two_objectives)
    b = make(torch.zeros(2, 4, dtype=F64), seed=7, max_iter=5, tol=0.0).minimize(two_objectives)
    c = make(torch.zeros(2, 4, dtype=F64), seed=8, max_iter=5, tol=0.0).minimize(two_objectives)
    assert torch.equal(a.mean, b.mean) and torch.equal(a.var, b.var)
    for k in a.history:
        assert torch.equal(a.history[k], b.history[k]), k
    assert not torch.equal(a.mean, c.mean)


def test_minimize_improves_a_quadratic(make):
    target = torch.tensor([1.0, -0.5, 0.25, 2.0], dtype=F64)

    def quad(w):
        return (w - target).pow(2).sum(-1, keepdim=True)

    mean0 = torch.zeros(4, dtype=F64)
    opt = make(mean0, beta=2.0, num_samples=50, max_iter=30, num_objectives=1)
    calls = []
    res = opt.minimize(quad, callback=lambda o: calls.append(o.iteration))
    assert calls == list(range(1, res.iterations + 1))  # once per iteration
    assert quad(res.mean).item() < 0.5 * quad(mean0).item()
    costs = res.history["cost"][:, 0]
    assert costs[-3:].mean() < 0.5 * costs[0]


# --------------------------------------------------------------------------- result
def test_result_and_history_shapes_batched(make):
    b, n, o, iters = 3, 4, 2, 3
    opt = make(torch.zeros(b, n, dtype=F64), max_iter=iters, tol=0.0)
    res = opt.minimize(two_objectives)
    assert isinstance(res, OptimizeResult)
    assert res.mean.shape == res.var.shape == (b, n) and res.converged.shape == (b,)
    assert res.converged.dtype == torch.bool and res.iterations == iters
    assert res.history["cost"].shape == (iters, b, o)
    assert res.history["mean"].shape == res.history["var"].shape == (iters, b, n)
    assert torch.equal(res.history["mean"][-1], res.mean) and torch.equal(
        res.history["var"][-1], res.var
    )
    if issubclass(make.cls, PRO):
        assert res.history["relevance"].shape == (iters, b, o, n)
    assert bool(torch.isfinite(res.history["cost"]).all())
    # the result is a copy: stepping on does not change it
    before = res.mean.clone()
    opt.max_iter += 1
    opt.minimize(two_objectives)
    assert torch.equal(res.mean, before)


def test_result_and_history_shapes_unbatched(make):
    n, o, iters = 4, 2, 3
    res = make(torch.zeros(n, dtype=F64), max_iter=iters, tol=0.0).minimize(two_objectives)
    assert res.mean.shape == res.var.shape == (n,) and res.converged.shape == ()
    assert res.history["cost"].shape == (iters, o)
    assert res.history["mean"].shape == res.history["var"].shape == (iters, n)
    if issubclass(make.cls, PRO):
        assert res.history["relevance"].shape == (iters, o, n)


def test_history_cost_is_mean_cost_of_the_update_samples(make):
    opt = make(torch.zeros(4, dtype=F64), max_iter=1, tol=0.0, num_objectives=1)
    told = []
    while not opt.stop():
        w = opt.ask()
        c = (w - 1).pow(2).sum(-1, keepdim=True)
        if w.shape[0] == 20:  # the update samples (not relevance probes)
            told.append(c.mean())
        opt.tell(c)
    assert len(told) == 1
    torch.testing.assert_close(opt.result().history["cost"][0, 0], told[0])


def test_float32(make):
    opt = make(torch.zeros(2, 4, dtype=torch.float32), max_iter=5, tol=0.0)
    assert opt.mean.dtype == opt.var.dtype == opt.beta.dtype == torch.float32
    asked = []
    res = opt.minimize(lambda w: asked.append(w.dtype) or two_objectives(w))
    assert set(asked) == {torch.float32}
    assert res.mean.dtype == res.var.dtype == torch.float32
    assert all(v.dtype == torch.float32 for k, v in res.history.items()), {
        k: v.dtype for k, v in res.history.items()
    }
    assert bool(torch.isfinite(res.mean).all()) and bool((res.var >= 0).all())
    assert two_objectives(res.mean).sum() < two_objectives(torch.zeros(2, 4)).sum()


def test_integer_costs_are_accepted(make):
    opt = make(torch.zeros(4, dtype=F64), max_iter=1, tol=0.0)
    while not opt.stop():
        w = opt.ask()
        opt.tell((two_objectives(w) * 10).round().long())
    assert opt.iteration == 1


def test_to_moves_the_distribution(make):
    """``opt.to(dtype)`` is ``nn.Module.to``: the distribution's buffers change dtype and the
    optimiser still asks and tells (no update method shadows ``nn.Module._apply``)."""
    opt = make(torch.zeros(3, dtype=F64))
    assert opt.to(torch.float32) is opt and opt.mean.dtype == torch.float32
    assert opt.var.dtype == torch.float32
    one_iteration(opt, two_objectives)
    assert opt.iteration == 1
