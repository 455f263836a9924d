"""EPRO (protorch.optim.efficient_pro): its update equations, the variance it keeps on weights no
objective reads, batched problems, devices and bad input."""

import pytest
import torch

from protorch.optim import EPRO, OPTIMIZERS, PRO, noise_floor_threshold
from protorch.optim.efficient_pro import (
    curvature_relevance,
    effective_pool_size,
    ess_temperature,
    gated_relevance,
)
from tests.optim.test_contract import *  # noqa: F401,F403  the contract suite, run here for EPRO (make below)

F64 = torch.float64


@pytest.fixture
def make():
    """The contract suite's builder, for EPRO alone."""

    def build(mean, var=1.0, **kw):
        kw.setdefault("beta", 1.0)
        kw.setdefault("num_samples", 20)
        kw.setdefault("num_objectives", 2)
        kw.setdefault("seed", 0)
        return EPRO(mean, torch.as_tensor(var, dtype=F64), **kw)

    build.cls = EPRO
    return build


def test_registered_and_exported():
    import protorch.optim as optim

    assert OPTIMIZERS["epro"] is EPRO and "EPRO" in optim.__all__


def test_ess_temperature_hits_the_target():
    costs = torch.rand(3, 50, generator=torch.Generator().manual_seed(0), dtype=F64) * torch.tensor(
        [[1.0], [1e-4], [1e3]], dtype=F64
    )
    beta = ess_temperature(costs, 0.25)  # (3,)
    r = torch.exp(-beta[:, None] * (costs - costs.amin(-1, keepdim=True)))
    ess = r.sum(-1) ** 2 / r.pow(2).sum(-1)
    torch.testing.assert_close(ess, torch.full_like(ess, 12.5), rtol=1e-6, atol=1e-6)
    # the same selection pressure at any cost scale: beta scales as 1 / cost
    torch.testing.assert_close(
        beta[1] * 1e-4 / beta[0], torch.tensor(1.0, dtype=F64), rtol=0.5, atol=0
    )
    assert ess_temperature(torch.ones(2, 10, dtype=F64), 0.5).tolist() == [
        1.0,
        1.0,
    ]  # constant: no NaN
    with pytest.raises(ValueError, match="ess"):
        ess_temperature(costs, 0.0)


def test_curvature_relevance_sees_a_v_shaped_cost():
    g = torch.Generator().manual_seed(1)
    w = torch.randn(400, 3, generator=g, dtype=F64)  # (P, 3)
    costs = torch.stack(
        [w[:, 0].abs(), w[:, 1]], -1
    )  # (P, 2): V-shaped in w0 at the mean, linear in w1
    f = curvature_relevance(w, costs, torch.zeros(3, dtype=F64), noise_floor=3.0)  # (2, 3)
    linear_only = torch.corrcoef(torch.stack([w[:, 0], costs[:, 0]]))[0, 1].abs()
    assert linear_only < noise_floor_threshold(400, 3.0)  # Pearson alone misses w0 ...
    assert f[0, 0] == 1.0 and f[1, 1] == 1.0  # ... the squared deviation sees it
    assert f[0, 2] == 0 and f[1, 2] == 0 and f[0, 1] == 0  # w2 is read by nothing


def test_update_without_the_gate_matches_the_equations():
    """``evidence_level=None``, one iteration by hand: ESS-tempered rewards on the summed costs,
    relevance from the batch, mean' = mean + f (sum R w - mean), var' = (1 - f) var + f sum R (w
    - mean)^2."""
    mean, var = torch.tensor([0.5, -0.2, 0.0], dtype=F64), torch.tensor([1.0, 0.5, 2.0], dtype=F64)
    opt = EPRO(mean, var, num_samples=30, seed=3, pool=1, ess=0.3, evidence_level=None)
    fn = lambda w: torch.stack([(w[..., 0] - 1) ** 2, (w[..., 1] + 1) ** 2], -1)  # noqa: E731
    w = opt.ask()  # (S, 3)
    c = fn(w)
    opt.tell(c)
    f = curvature_relevance(w, c, mean, 3.0).amax(0)  # (3,)
    total = c.sum(-1)
    beta = ess_temperature(total, 0.3)
    r = torch.exp(-beta * (total - total.min()))
    r = r / r.sum()
    torch.testing.assert_close(opt.mean[0], mean + f * (r @ w - mean))
    torch.testing.assert_close(opt.var[0], (1 - f) * var + f * (r @ (w - mean) ** 2))
    assert f[2] == 0 and opt.mean[0, 2] == 0 and opt.var[0, 2] == 2.0


def test_update_with_the_gate_matches_the_equations():
    """Defaults, the iteration after some weights were shown to be read, by hand: a read weight's
    mean goes to the reward-weighted mean and its variance blends with g; a weight not shown to be
    read keeps its variance exactly and its mean steps max(f, provisional_step) of the way there,
    within the
    trust region."""
    n = 6
    fn = lambda w: torch.stack(
        [(w[..., 0] - 3) ** 2 + (w[..., 1] - 3) ** 2, (w[..., 2] + 3) ** 2], -1
    )  # noqa: E731
    opt = EPRO(torch.zeros(n, dtype=F64), torch.ones(n, dtype=F64), tol=0, seed=4)
    for _ in range(8):
        opt.tell(fn(opt.ask()))
    assert opt.read[0, :3].any() and not opt.read[0, 3:].any()
    mean, var, t = opt.mean[0].clone(), opt.var[0].clone(), opt.iteration + 1
    w = opt.ask()
    c = fn(w)
    opt.tell(c)
    total = c.sum(-1)
    assert (opt.ess, opt.provisional_step) == (0.2, 0.75)  # the defaults (docs/peers.md 3d)
    r = torch.exp(-ess_temperature(total, opt.ess) * (total - total.min()))
    r = r / r.sum()
    target, spread = r @ w, r @ (w - mean) ** 2
    read = opt.read[0]
    f, g = opt.relevance[0].amax(0), (opt.variance_relevance[0] * read).amax(0)  # (N,) each
    radius = 3.0 * min(1.0, (5 / t) ** 0.5)
    provisional = (mean + f.clamp_min(opt.provisional_step) * (target - mean)).clamp(
        -radius, radius
    )
    torch.testing.assert_close(opt.mean[0], torch.where(read, target, provisional))
    torch.testing.assert_close(opt.var[0], (1 - g) * var + g * spread)
    assert (opt.var[0, ~read] == 1).all() and (opt.mean[0, ~read].abs() <= radius).all()


def test_fixed_beta_is_the_reward_temperature():
    mean, var = torch.zeros(2, dtype=F64), torch.ones(2, dtype=F64)
    opt = EPRO(
        mean, var, beta=5.0, num_samples=40, seed=0, pool=1, noise_floor=None, evidence_level=None
    )
    w = opt.ask()
    c = (w - 1).pow(2)  # (S, 2)
    opt.tell(c)
    r = torch.softmax(-5.0 * c.sum(-1), 0)
    f = curvature_relevance(w, c, mean, None).amax(0)
    torch.testing.assert_close(opt.mean[0], f * (r @ w))


def test_irrelevant_weights_keep_their_variance_and_mean():
    """Quadratic on 3 of 8 weights: EPRO solves it, shows the 3 to be read and no other, and the
    other 5 keep their std exactly and their mean within the trust region; RWR-style collapse would
    take them down with the rest."""
    n = 8
    opt = EPRO(torch.zeros(n, dtype=F64), torch.ones(n, dtype=F64), max_iter=60, tol=0, seed=0)
    res = opt.minimize(
        lambda w: torch.stack([(w[..., :3] - 2).pow(2).sum(-1), (w[..., 0] - 2).abs()], -1)
    )
    assert (res.mean[:3] - 2).abs().max() < 0.1
    assert opt.read[0].tolist() == [True] * 3 + [False] * 5
    assert (res.var[3:] == 1).all()
    assert res.mean[3:].abs().max() <= 3.0 * (5 / 60) ** 0.5 + 1e-12
    assert res.var[:3].sqrt().max() < 0.2  # the relevant ones did shrink


def test_batched_problems_are_independent():
    means = torch.tensor([[0.0, 0.0], [3.0, -3.0]], dtype=F64)
    targets = torch.tensor([[1.0, 1.0], [-1.0, 2.0]], dtype=F64)
    opt = EPRO(means, torch.ones(2, 2, dtype=F64), max_iter=80, tol=0, seed=1)
    res = opt.minimize(lambda w: (w - targets[:, None]).pow(2))  # (B, S, 2)
    assert res.mean.shape == (2, 2) and res.history["relevance"].shape == (80, 2, 2, 2)
    torch.testing.assert_close(res.mean, targets, atol=0.1, rtol=0)


def test_one_batch_per_iteration_and_seeded():
    run = lambda: EPRO(
        torch.zeros(4, dtype=F64), torch.ones(4, dtype=F64), max_iter=5, tol=0, seed=7
    ).minimize(  # noqa: E731
        lambda w: w.pow(2)
    )
    a, b = run(), run()
    torch.testing.assert_close(a.mean, b.mean, rtol=0, atol=0)
    opt = EPRO(
        torch.zeros(4, dtype=F64),
        torch.ones(4, dtype=F64),
        num_samples=12,
        max_iter=3,
        tol=0,
        seed=0,
    )
    asked = 0
    while not opt.stop():
        w = opt.ask()
        asked += w.shape[0]
        opt.tell(w.pow(2))
    assert asked == 3 * 12  # versus PRO's relevance probes + one batch per objective
    pro = PRO(
        torch.zeros(4, dtype=F64),
        torch.ones(4, dtype=F64),
        beta=1.0,
        num_samples=12,
        max_iter=1,
        tol=0,
        relevance_samples=20,
        seed=0,
    )
    pro_asked = 0
    while not pro.stop():
        w = pro.ask()
        pro_asked += w.shape[0]
        pro.tell(w.pow(2))
    assert pro_asked == 20 + 4 * 12


def test_constant_costs_do_not_move_or_nan():
    opt = EPRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), max_iter=3, tol=0, seed=0)
    res = opt.minimize(lambda w: torch.ones(*w.shape[:-1], 2, dtype=F64))
    assert torch.isfinite(res.var).all() and (res.var == 1).all() and (res.mean == 0).all()


@pytest.mark.parametrize(
    "device",
    [
        "cpu",
        pytest.param(
            "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no cuda")
        ),
    ],
)
def test_device_follows_the_mean(device):
    opt = EPRO(
        torch.zeros(2, 3, dtype=torch.float32, device=device), 1.0, max_iter=4, tol=0, seed=0
    )
    res = opt.minimize(lambda w: (w - 1).pow(2))
    assert (
        res.mean.device.type == device
        and res.mean.dtype == torch.float32
        and torch.isfinite(res.mean).all()
    )


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"ess": 0.0}, "ess"),
        ({"ess": 1.5}, "ess"),
        ({"pool": 0}, "pool"),
        ({"noise_floor": -1.0}, "noise_floor"),
        ({"beta": -1.0}, "beta"),
        ({"num_samples": 1}, "num_samples"),
        ({"evidence_level": 0.0}, "evidence_level"),
        ({"evidence_level": 1.0}, "evidence_level"),
        ({"trust_radius": -1.0}, "trust_radius"),
        ({"trust_iterations": 0}, "trust_iterations"),
        ({"provisional_step": 1.5}, "provisional_step"),
    ],
)
def test_bad_settings(kw, match):
    with pytest.raises(ValueError, match=match):
        EPRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), **kw)


def test_bad_costs():
    opt = EPRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), seed=0)
    w = opt.ask()
    with pytest.raises(ValueError, match="costs"):
        opt.tell(torch.zeros(w.shape[0] + 1, 2, dtype=F64))
    with pytest.raises(ValueError):
        opt.tell(torch.full((w.shape[0], 2), float("nan"), dtype=F64))


def test_linear_relevance_option_is_the_papers_pearson():
    from protorch.optim import pearson_relevance

    mean, var = torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64)
    opt = EPRO(
        mean,
        var,
        num_samples=40,
        seed=2,
        pool=1,
        curvature=False,
        noise_floor=3.0,
        variance_floor=None,
    )
    w = opt.ask()
    c = torch.stack([w[:, 0].abs(), w[:, 1]], -1)  # (S, 2)
    opt.tell(c)
    torch.testing.assert_close(opt.relevance[0], pearson_relevance(w, c, noise_floor=3.0))


def test_standardized_pool_undoes_a_drifting_distribution():
    """Samples of an unread weight whose mean and std change every batch: pooled raw, their
    squared deviation from the last mean tracks a cost that falls with the batch; standardised by
    each batch's own distribution they are N(0, 1) and uncorrelated with it."""
    from protorch.optim.efficient_pro import standardize_batch

    g = torch.Generator().manual_seed(0)
    batches, raw, std = 10, [], []
    for t in range(batches):
        mean, var = (
            torch.tensor([[0.1 * t]], dtype=F64),
            torch.tensor([[0.8**t]], dtype=F64),
        )  # (1, 1)
        w = mean[:, None] + var.sqrt()[:, None] * torch.randn(
            1, 50, 1, generator=g, dtype=F64
        )  # (1, 50, 1)
        raw.append(w)
        std.append(standardize_batch(w, mean, var))
    cost = (
        torch.arange(batches, dtype=F64).flip(0).repeat_interleave(50)[None, :, None]
    )  # (1, 500, 1)
    raw, std = torch.cat(raw, 1), torch.cat(std, 1)  # (1, 500, 1)
    last = torch.tensor([[0.9]], dtype=F64)
    assert curvature_relevance(raw, cost, last, 3.0)[0, 0, 0] > 0  # a false relevance
    assert curvature_relevance(std, cost, torch.zeros(1, 1, dtype=F64), 3.0)[0, 0, 0] == 0
    assert abs(std.mean().item()) < 0.15 and abs(std.var().item() - 1) < 0.2
    assert (
        standardize_batch(
            torch.ones(1, 3, 1, dtype=F64),
            torch.ones(1, 1, dtype=F64),
            torch.zeros(1, 1, dtype=F64),
        )
        .abs()
        .max()
        == 0
    )


def test_effective_pool_size_counts_batches_by_their_cost_spread():
    g = torch.Generator().manual_seed(0)
    same = [torch.randn(20, 2, generator=g, dtype=F64) for _ in range(10)]  # equal spreads
    p_same = effective_pool_size([c / c.std(0, unbiased=False) for c in same])
    torch.testing.assert_close(p_same, torch.full((2,), 200.0, dtype=F64))
    wide = [same[0] * 1e3] + same[1:]  # one batch dominates the pooled correlation
    assert (effective_pool_size(wide) < 21).all()
    flat = [torch.zeros(20, 1, dtype=F64)] * 3  # a constant objective counts as the whole pool
    assert effective_pool_size(flat).item() == 60


def test_variance_gate_is_stricter_than_the_mean_gate():
    """A weight correlated between the two floors moves its mean only; one far above both moves
    both; an unread one neither."""
    g = torch.Generator().manual_seed(1)
    p = 400
    z = lambda x: (x - x.mean()) / x.std(unbiased=False)  # noqa: E731
    w0 = torch.randn(p, generator=g, dtype=F64)
    c = z(5 * w0 + torch.randn(p, generator=g, dtype=F64))  # (P,), |rho(w0, c)| ~ 0.98
    off = [
        z(e - (e @ c) / p * c) for e in torch.randn(2, p, generator=g, dtype=F64)
    ]  # uncorrelated with c
    w = torch.stack(
        [w0, 0.15 * c + (1 - 0.15**2) ** 0.5 * off[0], off[1]], -1
    )  # (P, 3): strong, weak, unread
    cost = c[:, None]  # (P, 1)
    p_eff = torch.full((1,), float(p), dtype=F64)  # floors 2.5 / 20 = 0.125 and 3.5 / 20 = 0.175
    f, gv = gated_relevance(
        w, cost, torch.zeros(3, dtype=F64), p_eff, 2.5, 3.5, curvature=False
    )  # (1, 3) each
    assert f[0, 0] == 1 and f[0, 1] > 0 and f[0, 2] == 0
    assert gv[0, 0] == 1 and gv[0, 1] == 0 and gv[0, 2] == 0
    f2, g2 = gated_relevance(w, cost, torch.zeros(3, dtype=F64), p_eff, 2.5, None, curvature=False)
    torch.testing.assert_close(f2, f)
    torch.testing.assert_close(g2, f)  # variance_floor=None: the mean's relevance for both


def noisy_quadratic(seed: int):
    """Costs of 8 weights that read the first 3, plus uniform noise of width 0.1 (a stochastic
    rollout): past convergence every correlation is noise, where chance relevance accumulates."""
    g = torch.Generator().manual_seed(seed)

    def fn(w):  # (B, S, 8) -> (B, S, 2)
        c = torch.stack([(w[..., :3] - 2).pow(2).sum(-1), (w[..., 0] - 2).abs()], -1)
        return c + 0.1 * torch.rand(c.shape, generator=g, dtype=c.dtype)

    return fn


LONG = 600  # iterations (12,000 samples per problem), most of them past convergence


@pytest.mark.parametrize("gate", [True, False], ids=["evidence", "no evidence"])
def test_unread_weights_stay_put_for_hundreds_of_iterations(gate, one_thread):
    """Two problems, 600 iterations on the noisy quadratic. With the read-weight test the 5 unread
    weights keep their std exactly and end within the trust region (0.27 initial stds at 600
    iterations) while the 3 read ones are solved. Without it (``evidence_level=None``, the
    relevance floors alone) chance correlations pile up: the same run ends with an unread std of
    0.74 and an unread mean 3.1 initial stds from its start."""
    opt = EPRO(
        torch.zeros(2, 8, dtype=F64),
        torch.ones(2, 8, dtype=F64),
        max_iter=LONG,
        tol=0,
        seed=0,
        **({} if gate else {"evidence_level": None}),
    )
    res = opt.minimize(noisy_quadratic(0))
    kept, drift = res.var[:, 3:].sqrt().min().item(), res.mean[:, 3:].abs().max().item()
    if gate:
        assert (res.mean[:, :3] - 2).abs().max() < 0.15 and res.var[:, :3].sqrt().max() < 0.1
        assert opt.read[:, :3].all() and not opt.read[:, 3:].any()
        assert (res.var[:, 3:] == 1).all()
        assert drift <= 3.0 * (5 / LONG) ** 0.5 + 1e-12
    else:
        assert kept < 0.9 or drift > 1.0, (kept, drift)
