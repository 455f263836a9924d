"""The peers behind the ask / tell contract: CEM's update equations, and CMA-ES being pycma itself
(wrapped, not re-implemented) started from the given mean and stds. The contract suite
(test_contract.py) runs on both as well."""

import math

import cma
import numpy as np
import pytest
import torch

from protorch.optim import CEM, CMAES

F64 = torch.float64


# ------------------------------------------------------------------------------ CEM
@pytest.mark.parametrize("smoothing, extra_var", [(1.0, 0.0), (0.7, 0.05)])
def test_cem_update_is_the_elite_refit(smoothing, extra_var):
    mean0 = torch.tensor([[0.5, -1.0, 2.0], [0.0, 0.0, 0.0]], dtype=F64)  # (B, N)
    var0 = torch.tensor([[1.0, 0.5, 2.0], [0.2, 0.2, 0.2]], dtype=F64)
    opt = CEM(
        mean0,
        var0,
        num_samples=20,
        elite_frac=0.25,
        smoothing=smoothing,
        extra_var=extra_var,
        objective_weights=[1.0, 3.0],
        seed=3,
        tol=0.0,
    )
    w = opt.ask()  # (2, 20, 3)
    costs = torch.stack([w[..., 0].abs(), (w[..., 1] - 1).pow(2)], -1)  # (2, 20, 2)
    opt.tell(costs)
    total = costs[..., 0] + 3 * costs[..., 1]  # (2, 20)
    for b in range(2):
        elite = w[b, total[b].argsort()[:5]]  # ceil(0.25 * 20) = 5 lowest totals
        m = elite.mean(0)
        v = ((elite - m) ** 2).mean(0)
        torch.testing.assert_close(opt.mean[b], (1 - smoothing) * mean0[b] + smoothing * m)
        torch.testing.assert_close(
            opt.var[b], (1 - smoothing) * var0[b] + smoothing * v + extra_var
        )


def test_cem_is_rank_based():
    """Any increasing transform of the costs gives the same run."""

    def run(transform):
        opt = CEM(
            torch.zeros(4, dtype=F64),
            torch.ones(4, dtype=F64),
            num_samples=30,
            max_iter=5,
            tol=0.0,
            seed=1,
        )
        return opt.minimize(lambda w: transform((w - 1).pow(2).sum(-1))).mean

    torch.testing.assert_close(
        run(lambda c: c), run(lambda c: torch.exp(3 * c) + 7), rtol=0, atol=0
    )


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"elite_frac": 0.0}, "elite_frac"),
        ({"elite_frac": 1.5}, "elite_frac"),
        ({"smoothing": 0.0}, "smoothing"),
        ({"extra_var": -1.0}, "extra_var"),
    ],
)
def test_cem_bad_settings(kw, message):
    with pytest.raises(ValueError, match=message):
        CEM(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), **kw)


# ------------------------------------------------------------------------------ CMA-ES
def test_cmaes_starts_from_the_given_mean_and_stds():
    mean = torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    std = torch.tensor([0.01, 1.0, 10.0], dtype=F64)
    opt = CMAES(mean, std**2, num_samples=4000, seed=0)
    w = opt.ask()  # (4000, 3): the first generation is N(mean, diag(std^2))
    torch.testing.assert_close(w.mean(0), mean, atol=float(4 * std.max() / math.sqrt(4000)), rtol=0)
    torch.testing.assert_close(w.std(0) / std, torch.ones(3, dtype=F64), atol=0.05, rtol=0)
    torch.testing.assert_close(opt.var, std[None] ** 2)  # es.stds before any update


def test_cmaes_is_pycma_itself():
    """Same seed, same options, same costs: the wrapper's means and stds are a raw pycma run's."""
    n, s, seed = 5, 12, 4
    mean0, std0 = np.linspace(-1, 1, n), np.linspace(0.5, 1.5, n)
    opt = CMAES(
        torch.tensor(mean0), torch.tensor(std0**2), num_samples=s, seed=seed, tol=0.0, max_iter=8
    )
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, 0])))
    es = cma.CMAEvolutionStrategy(
        mean0,
        1.0,
        {
            "CMA_stds": std0,
            "popsize": s,
            "seed": float("nan"),
            "randn": lambda *shape: rng.standard_normal(shape),
            "verbose": -9,
        },
    )

    def f(x):  # (..., N) -> (...): a rotated ellipsoid
        return (np.cumsum(np.asarray(x), -1) ** 2 * np.arange(1, n + 1)).sum(-1)

    for _ in range(8):
        w = opt.ask()
        opt.tell(torch.as_tensor(f(w.numpy())))
        x = es.ask()
        es.tell(x, [float(f(xi)) for xi in x])
        np.testing.assert_allclose(w.numpy(), np.asarray(x), rtol=1e-12, atol=0)
        np.testing.assert_allclose(opt.mean[0].numpy(), es.mean, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(opt.var[0].numpy(), np.asarray(es.stds) ** 2, rtol=1e-12)


def test_cmaes_leaves_numpys_global_random_state_alone():
    before = np.random.get_state()[1].copy()
    opt = CMAES(
        torch.zeros(3, 3, dtype=F64), torch.ones(3, dtype=F64), num_samples=10, max_iter=3, seed=0
    )
    opt.minimize(lambda w: w.pow(2).sum(-1))
    assert np.array_equal(np.random.get_state()[1], before)


def test_cmaes_beats_a_diagonal_method_on_a_rotated_valley():
    """What full covariance adaptation buys: a narrow valley along (1, 1, ..., 1)."""
    n = 6
    d = torch.ones(n, dtype=F64) / math.sqrt(n)

    def valley(w):  # (..., N) -> (...)
        along = w @ d
        return (along - 3.0) ** 2 + 100 * (w - along[..., None] * d).pow(2).sum(-1)

    start = dict(num_samples=20, max_iter=150, tol=0.0, seed=0)
    cma_res = CMAES(torch.zeros(n, dtype=F64), torch.ones(n, dtype=F64), **start).minimize(valley)
    cem_res = CEM(torch.zeros(n, dtype=F64), torch.ones(n, dtype=F64), **start).minimize(valley)
    assert valley(cma_res.mean) < 1e-6
    assert valley(cma_res.mean) < valley(cem_res.mean)


def test_cmaes_stops_a_problem_when_pycma_says_so():
    def fn(w):  # problem 0: constant (pycma's flat-fitness / tolfun stop), problem 1: a quadratic
        c = (w - 1).pow(2).sum(-1)
        c[0] = 1.0
        return c

    opt = CMAES(
        torch.zeros(2, 3, dtype=F64),
        torch.ones(3, dtype=F64),
        num_samples=10,
        max_iter=20,
        tol=0.0,
        seed=0,
    )
    res = opt.minimize(fn)
    assert res.converged.tolist() == [True, False] and res.iterations == 20
    assert "tolflatfitness" in opt.stop_reasons[0] or "tolfun" in opt.stop_reasons[0]
    frozen = res.history["mean"][:, 0]
    assert torch.equal(frozen, frozen[:1].expand_as(frozen))  # stopped after its first iteration
    off = CMAES(
        torch.zeros(2, 3, dtype=F64),
        torch.ones(3, dtype=F64),
        num_samples=10,
        max_iter=20,
        tol=0.0,
        seed=0,
        pycma_stop=False,
    ).minimize(fn)
    assert not bool(off.converged.any())


@pytest.mark.parametrize(
    "kw, error, message",
    [
        ({"var": 0.0}, ValueError, "var > 0"),
        ({"cma_options": {"popsize": 7}}, ValueError, "may not set"),
        ({"beta": 1.0}, TypeError, "no beta"),
    ],
)
def test_cmaes_bad_settings(kw, error, message):
    kw = {"var": 1.0, **kw}
    var = torch.full((3,), kw.pop("var"), dtype=F64)
    with pytest.raises(error, match=message):
        CMAES(torch.zeros(3, dtype=F64), var, **kw)
