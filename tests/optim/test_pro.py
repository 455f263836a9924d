"""PRO (and RWR, its relevance-1 baseline): the optimiser matches the functional core step by
step, irrelevant variance is kept exactly, and the Fig. 3 toy at a reduced budget."""

import pytest
import torch

from protorch import PRO, RWR, pearson_relevance, pro_update

F64 = torch.float64


def fig3_cost(w):
    """The Fig. 3 toy: distance to the line w2 = 2, on which w1 does not matter. ``(..., 1)``."""
    return (w[..., 1:2] - 2.0).abs()


def two_objectives(w):
    return torch.stack([(w[..., 0] - 1) ** 2, (w[..., 2] + 1).abs()], -1)


# ------------------------------------------------------------ step = functional core
def test_one_iteration_is_relevance_then_pro_update_per_objective():
    beta = torch.tensor([1.0, 10.0], dtype=F64)  # one beta per problem
    opt = PRO(
        torch.zeros(2, 4, dtype=F64),
        torch.tensor([1.0, 2.0, 0.5, 1.5], dtype=F64),
        beta=beta,
        num_samples=30,
        relevance_samples=40,
        relevance_var=1e-4,
        noise_floor=2.0,
        seed=3,
        tol=0.0,
    )
    # 1. the relevance probes: drawn around the mean with the small variance relevance_var
    probe = opt.ask()
    assert probe.shape == (2, 40, 4)
    assert float((probe - opt.mean[:, None]).pow(2).mean()) == pytest.approx(1e-4, rel=0.2)
    probe_costs = two_objectives(probe)
    opt.tell(probe_costs)
    f = pearson_relevance(probe, probe_costs, noise_floor=2.0)  # (B, O, N)
    torch.testing.assert_close(opt.relevance, f, rtol=0, atol=0)
    assert bool((f[:, 0, 0] == 1).all()) and bool((f[:, 1, 2] == 1).all())
    assert bool((f[:, :, 3] == 0).all())  # w_3 affects no objective
    # 2. one PRO update per objective, in turn, with samples from N(mean, var * f_o)
    for o in range(2):
        mean, var = opt.mean.clone(), opt.var.clone()
        w = opt.ask()
        assert w.shape == (2, 30, 4)
        irrelevant = f[:, o] == 0  # (B, N)
        assert torch.equal(w.transpose(1, 2)[irrelevant], mean[irrelevant][:, None].expand(-1, 30))
        costs = two_objectives(w)
        opt.tell(costs)
        for b in range(2):
            m, v = pro_update(mean[b], var[b], w[b], costs[b, :, o], f[b, o], float(beta[b]))
            torch.testing.assert_close(opt.mean[b], m, rtol=1e-14, atol=1e-14)
            torch.testing.assert_close(opt.var[b], v, rtol=1e-14, atol=1e-14)
    assert opt.iteration == 1


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_pro_moves_weights_of_large_magnitude(dtype):
    # weights of trajectories in, say, millimetres: the relevance probes (variance 1e-5) must
    # still see the relevant weight in float32, or PRO silently stops moving
    mean = torch.tensor([1000.0, -800.0], dtype=dtype)
    opt = PRO(mean, 1.0, beta=1.0, num_samples=50, max_iter=20, tol=0.0, seed=0)
    res = opt.minimize(lambda w: (w[..., :1] - 1002.0).abs())
    assert bool((res.history["relevance"][0, 0] == torch.tensor([1.0, 0.0], dtype=dtype)).all())
    assert abs(res.mean[0].item() - 1002.0) < 0.5
    assert res.var[1].item() == 1.0


def test_num_objectives_is_inferred_from_the_first_tell():
    opt = PRO(
        torch.zeros(3, dtype=F64), 1.0, beta=1.0, num_samples=10, relevance_samples=20, seed=0
    )
    asks = 0
    while opt.iteration == 0:
        w = opt.ask()
        asks += 1
        opt.tell(torch.stack([w[:, 0] ** 2, w[:, 1] ** 2, w[:, 2] ** 2], -1))
    assert opt.num_objectives == 3 and asks == 1 + 3


# ------------------------------------------------------------ irrelevant variance
def test_zero_relevance_weight_keeps_its_variance_exactly_over_many_iterations():
    # the cost depends on w_0 only: w_1 and w_2 are irrelevant, their variance must not move
    var0 = torch.tensor([1.0, 0.7, 2.3], dtype=F64)
    opt = PRO(
        torch.zeros(3, 3, dtype=F64), var0, beta=5.0, num_samples=100, max_iter=150, tol=0.0, seed=0
    )
    res = opt.minimize(lambda w: (w[..., :1] - 1.0).abs())
    assert res.iterations == 150
    rel = res.history["relevance"]  # (I, B, 1, N)
    # the property itself, for any seed: an iteration in which a weight's relevance is 0 leaves
    # its variance bit-for-bit unchanged
    var_hist = torch.cat([var0.expand(1, 3, 3), res.history["var"]])  # (I + 1, B, N)
    zero = rel[:, :, 0] == 0  # (I, B, N)
    assert torch.equal(var_hist[1:][zero], var_hist[:-1][zero])
    # and with this seed the 4-sigma noise floor never let the irrelevant weights through
    assert bool((rel[..., 1:] == 0).all())
    assert torch.equal(res.history["var"][..., 1:], var0[1:].expand(150, 3, 2))
    torch.testing.assert_close(
        res.history["mean"][..., 1:], torch.zeros(150, 3, 2, dtype=F64), rtol=0, atol=1e-12
    )
    # while the relevant weight converged
    assert bool(((res.mean[:, 0] - 1).abs() < 0.05).all()) and bool((res.var[:, 0] < 1e-2).all())


@pytest.mark.slow
def test_fig3_toy_pro_keeps_irrelevant_std_and_rwr_collapses_it():
    # Fig. 3 at a reduced budget (300 iterations x 200 samples), 4 independent problems at once
    b, kw = 4, {"beta": 10.0, "num_samples": 200, "max_iter": 300, "tol": 0.0, "seed": 0}
    mean, var = torch.zeros(b, 2, dtype=F64), torch.ones(2, dtype=F64)
    pro = PRO(mean, var, **kw).minimize(fig3_cost)
    rwr = RWR(mean, var, **kw).minimize(fig3_cost)
    pro_std, rwr_std = pro.var.sqrt(), rwr.var.sqrt()  # (B, 2)
    assert bool(((pro_std[:, 0] - 1).abs() <= 0.2).all()), pro_std[:, 0]
    assert float(rwr_std[:, 0].mean()) < 0.35, rwr_std[:, 0]
    assert bool((rwr_std[:, 0] < 0.6 * pro_std[:, 0]).all())
    # both solve the relevant direction, with final rewards within 10% of each other
    for res in (pro, rwr):
        assert bool(((res.mean[:, 1] - 2).abs() < 0.05).all())
        assert bool((res.var[:, 1].sqrt() < 0.05).all())
    pro_reward = torch.exp(-10.0 * fig3_cost(pro.mean))
    rwr_reward = torch.exp(-10.0 * fig3_cost(rwr.mean))
    assert bool(((pro_reward - rwr_reward).abs() <= 0.1 * rwr_reward).all())


@pytest.mark.slow
def test_fig3_toy_without_noise_floor_drains_the_irrelevant_variance():
    # the paper's relevance as written: sampling noise in rho shrinks the irrelevant variance
    kw = {"beta": 10.0, "num_samples": 200, "max_iter": 300, "tol": 0.0, "seed": 0}
    res = PRO(torch.zeros(2, 2, dtype=F64), 1.0, noise_floor=None, **kw).minimize(fig3_cost)
    assert bool((res.var[:, 0].sqrt() < 0.5).all())


# -------------------------------------------------------------------------- relevance
def _count_probe_asks(opt, fn):
    probes = 0
    while not opt.stop():
        w = opt.ask()
        probes += int(w.shape[-2] == opt.relevance_samples)
        opt.tell(fn(w))
    return probes


def _probe_pro(mean, **kw):
    """A small PRO on ``two_objectives`` whose probe asks are recognisable by their size (30)."""
    return PRO(
        mean,
        1.0,
        **{"beta": 2.0, "num_samples": 20, "relevance_samples": 30, "tol": 0.0, "seed": 0, **kw},
    )


def test_relevance_every_zero_computes_relevance_once():
    opt = _probe_pro(torch.zeros(2, 3, dtype=F64), relevance_every=0, max_iter=6)
    assert _count_probe_asks(opt, two_objectives) == 1
    res = opt.result()
    assert len(res.relevance_seconds) == 1
    rel = res.history["relevance"]
    assert torch.equal(rel, rel[:1].expand_as(rel))


def test_relevance_every_k_recomputes_every_k_iterations():
    opt = _probe_pro(torch.zeros(3, dtype=F64), relevance_every=2, max_iter=5)
    assert _count_probe_asks(opt, two_objectives) == 3  # iterations 0, 2 and 4
    rel = opt.result().history["relevance"]
    assert torch.equal(rel[0], rel[1]) and torch.equal(rel[2], rel[3])
    assert len(opt.relevance_seconds) == 3


def test_relevance_seconds_recorded_every_iteration_by_default():
    opt = _probe_pro(torch.zeros(3, dtype=F64), max_iter=4)
    assert _count_probe_asks(opt, two_objectives) == 4
    secs = opt.result().relevance_seconds
    assert len(secs) == 4 and all(isinstance(s, float) and s > 0 for s in secs)


def test_relevance_history_in_unit_interval():
    res = PRO(
        torch.zeros(2, 4, dtype=F64), 1.0, beta=2.0, num_samples=20, max_iter=5, tol=0.0, seed=1
    ).minimize(two_objectives)
    rel = res.history["relevance"]
    assert bool(((rel >= 0) & (rel <= 1)).all())
    top = rel.amax(-1)
    assert bool(((top == 1) | (top == 0)).all())


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"relevance_samples": 2}, "relevance_samples must be an int >= 3"),
        ({"relevance_var": 0.0}, "relevance_var must be > 0"),
        ({"relevance_var": -1e-5}, "relevance_var must be > 0"),
        ({"relevance_every": -1}, "relevance_every must be an int >= 0"),
        ({"noise_floor": -1.0}, "noise_floor must be >= 0"),
    ],
)
def test_bad_pro_arguments_raise(kw, message):
    with pytest.raises(ValueError, match=message):
        PRO(torch.zeros(3), 1.0, beta=1.0, **kw)


# ------------------------------------------------------------ RWR: relevance 1 baseline
@pytest.mark.parametrize("center", ["new", "old"])
def test_rwr_step_is_weighted_maximum_likelihood(center):
    opt = RWR(
        torch.zeros(2, 3, dtype=F64),
        torch.tensor([1.0, 2.0, 0.5], dtype=F64),
        beta=torch.tensor([0.5, 3.0]),
        num_samples=25,
        center=center,
        objective_weights=[1.0, 2.0],
        seed=4,
    )
    mean, var = opt.mean.clone(), opt.var.clone()
    w = opt.ask()
    costs = two_objectives(w)
    opt.tell(costs)
    for b, beta in enumerate((0.5, 3.0)):
        r = torch.exp(-beta * (costs[b, :, 0] + 2.0 * costs[b, :, 1]))  # objectives combined
        r = r / r.sum()
        new_mean = (r[:, None] * w[b]).sum(0)
        around = new_mean if center == "new" else mean[b]
        new_var = (r[:, None] * (w[b] - around) ** 2).sum(0)
        torch.testing.assert_close(opt.mean[b], new_mean, rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(opt.var[b], new_var, rtol=1e-10, atol=1e-12)
    # old-centred RWR is PRO's update with every relevance 1
    if center == "old":
        m, v = pro_update(
            mean,
            var,
            w,
            costs @ torch.tensor([1.0, 2.0], dtype=F64),
            torch.ones_like(var),
            torch.tensor([0.5, 3.0], dtype=F64),
        )
        torch.testing.assert_close(opt.mean, m, rtol=0, atol=0)
        torch.testing.assert_close(opt.var, v, rtol=0, atol=0)


def test_rwr_bad_arguments_raise():
    with pytest.raises(ValueError, match="center must be 'new' or 'old'"):
        RWR(torch.zeros(3), 1.0, beta=1.0, center="mid")
    opt = RWR(torch.zeros(3), 1.0, beta=1.0, objective_weights=[1.0, 1.0, 1.0])
    w = opt.ask()
    with pytest.raises(ValueError, match=r"objective_weights must be \(2,\)"):
        opt.tell(two_objectives(w))


def test_asked_objective_names_the_only_column_an_update_reads():
    """None for the relevance probes (every objective), then 0, 1, ... for the per-objective
    updates; filling the other columns with zeros changes nothing."""
    runs, seen = [], []
    for sparse in (False, True):
        opt = PRO(
            torch.zeros(2, 4, dtype=torch.float64),
            torch.ones(2, 4, dtype=torch.float64),
            beta=2.0,
            num_samples=20,
            relevance_samples=20,
            max_iter=4,
            tol=0.0,
            seed=0,
        )
        while not opt.stop():
            w = opt.ask()
            o = opt.asked_objective
            if sparse:
                seen.append(o)
            c = two_objectives(w)
            if sparse and o is not None:
                keep = torch.zeros_like(c)
                keep[..., o] = c[..., o]
                c = keep
            opt.tell(c)
        runs.append(opt.result())
    assert seen == [None, 0, 1] * 4
    assert torch.equal(runs[0].mean, runs[1].mean) and torch.equal(runs[0].var, runs[1].var)


@pytest.mark.parametrize("cls, n", [(PRO, 20), (PRO, 70), (RWR, 70)])
def test_an_update_of_the_moving_problems_gives_them_the_numbers_of_one_over_all(
    cls, n, monkeypatch
):
    """Updates computed for the moving problems only (whole blocks of them: a BLAS kernel's
    rounding depends on the 64-byte alignment of each problem's matrices, and 70 float32
    weights per sample do not fill whole 64-byte lines) equal those computed for all B."""
    g = torch.Generator().manual_seed(0)
    mean, var = torch.randn(40, n, generator=g), torch.rand(40, n, generator=g)  # float32, B = 40
    done = torch.rand(40, generator=g) < 0.7

    def cost(w):
        return torch.stack(
            [(w[..., :5] - 1).pow(2).sum(-1), w[..., 5:].abs().mean(-1), w.sum(-1).abs()], -1
        )

    def run():
        opt = cls(
            mean,
            var,
            beta=5.0,
            num_samples=30,
            max_iter=6,
            tol=0.0,
            seed=1,
            **({"relevance_samples": 30} if cls is PRO else {}),
        )
        opt.mark_converged(done)
        return opt.minimize(cost)

    part = run()
    monkeypatch.setattr(
        cls, "_active_rows", lambda self: None
    )  # every problem, converged ones masked
    whole = run()
    assert torch.equal(part.mean, whole.mean) and torch.equal(part.var, whole.var)
    assert torch.equal(part.mean[done], mean[done])  # the converged ones never moved
