"""protorch.optim.evidence: EPRO's sequential read-weight test. Its e-values have expectation 1
when a weight is unread, the running statistic is the best start's evidence minus its threshold,
the surrogate's leave-one-out noise is what refitting without each sample gives, and the test
confirms read weights while it leaves unread ones alone."""

import math

import pytest
import torch

from protorch.optim.evidence import (
    NUM_TESTS,
    accumulate_evidence,
    batch_log_evidence,
    evidence_threshold,
    fit_surrogate,
    rank_scores,
    standard_scores,
)

F64 = torch.float64


def test_rank_scores_are_normal_quantiles_of_the_ranks():
    c = torch.tensor(
        [[3.0, 1.0], [1.0, 1.0], [2.0, 1.0], [2.0, 1.0]], dtype=F64
    )  # (S, O): a tie, a constant
    x = rank_scores(c)
    assert x[:, 1].abs().max() == 0  # a constant objective says nothing
    assert x[1, 0] < x[2, 0] == x[3, 0] < x[0, 0]  # order kept, ties share a score
    torch.testing.assert_close(x[:, 0].mean(), torch.tensor(0.0, dtype=F64))
    torch.testing.assert_close(x[:, 0].pow(2).mean(), torch.tensor(1.0, dtype=F64))
    torch.testing.assert_close(rank_scores(1e6 * c.exp()), x)  # monotone maps change nothing
    assert standard_scores(torch.full((5, 2), 7.0, dtype=F64)).abs().max() == 0


def _batches(g, p, n):
    """``p`` samples of ``n`` weights whose two costs read weight 0 only, as 20-sample batches'
    (eps, ranks, scores)."""
    eps = torch.randn(p // 20, 20, n, generator=g, dtype=F64)
    costs = torch.stack(
        [eps[..., 0] + 0.3 * eps[..., 0] ** 2, eps[..., 0].abs()], -1
    )  # (p / 20, 20, 2)
    return tuple(x.reshape(p, -1) for x in (eps, rank_scores(costs), standard_scores(costs)))


def test_log_e_values_are_ratios_of_densities():
    """Each alternative is a proper density of the batch's eps_n, fixed by the past and the costs:
    log e equals log q(eps_n) - log phi(eps_n) with q written out by torch.distributions."""
    from torch.distributions import MultivariateNormal, Normal

    g = torch.Generator().manual_seed(0)
    past, batch = _batches(g, 60, 4), _batches(g, 20, 4)
    eps, x, y = batch
    log_e = batch_log_evidence(*batch, *past)  # (3, N)
    phi = Normal(0.0, 1.0).log_prob(eps).sum(0)  # (N,)
    px, pe, py = past[1], past[0], past[2]
    a = px.T @ px + 4.0 * torch.eye(2, dtype=F64)  # prior std 0.5
    beta = torch.linalg.solve(a, px.T @ pe)  # (2, N)
    cov = torch.eye(20, dtype=F64) + x @ torch.linalg.solve(a, x.T)
    linear = (
        torch.stack([MultivariateNormal(x @ beta[:, k], cov).log_prob(eps[:, k]) for k in range(4)])
        - phi
    )
    torch.testing.assert_close(log_e[0], linear)
    gamma = 0.5 * torch.linalg.solve(a, px.T @ (pe**2 - 1))
    eta = (x @ gamma).clamp(-2, 2)  # (S, N)
    torch.testing.assert_close(log_e[1], Normal(0.0, (eta / 2).exp()).log_prob(eps).sum(0) - phi)
    coef, noise = fit_surrogate(pe, py)
    s2 = noise.clamp_min(0.05)
    for k in range(4):  # the posterior of eps_k given the costs and the other samples, by hand
        rest = y - eps @ coef + eps[:, k : k + 1] * coef[k]  # (S, O)
        prec = 1 + (coef[k] ** 2 / s2).sum()
        mu = (rest * coef[k] / s2).sum(-1) / prec
        log_q = Normal(mu, prec**-0.5).log_prob(eps[:, k]) - Normal(0.0, 1.0).log_prob(eps[:, k])
        torch.testing.assert_close(log_e[2, k], torch.log(0.5 + 0.5 * log_q.exp()).sum())


def test_e_values_average_one_over_unread_weights():
    """4,000 unread weights beside the read one (independent columns, one fit): the surrogate's
    and the scale's e-values average 1 (the linear one's are heavy-tailed: its density identity
    is checked above) and all three lose evidence on average."""
    g = torch.Generator().manual_seed(1)
    past, batch = _batches(g, 200, 4001), _batches(g, 20, 4001)
    log_e = batch_log_evidence(*batch, *past)[:, 1:]  # (3, 4000): the unread weights
    mean_e = log_e[1:].exp().mean(-1)  # scale, surrogate
    torch.testing.assert_close(mean_e, torch.ones_like(mean_e), atol=0.05, rtol=0)
    assert (log_e.mean(-1) < 0).all() and torch.isfinite(log_e).all()


def test_surrogate_noise_is_the_leave_one_out_residual():
    g = torch.Generator().manual_seed(1)
    for p, n in ((12, 30), (60, 5)):  # the kernel form (P < N) and the primal one
        eps = torch.randn(p, n, generator=g, dtype=F64)
        y = torch.randn(p, 2, generator=g, dtype=F64)
        coef, noise = fit_surrogate(eps, y, ridge=5.0)
        a = eps.T @ eps + 5.0 * torch.eye(n, dtype=F64)
        torch.testing.assert_close(coef, torch.linalg.solve(a, eps.T @ y))
        loo = []
        for i in range(p):
            keep = torch.arange(p) != i
            b = torch.linalg.solve(
                eps[keep].T @ eps[keep] + 5.0 * torch.eye(n, dtype=F64), eps[keep].T @ y[keep]
            )
            loo.append(y[i] - eps[i] @ b)
        torch.testing.assert_close(noise, torch.stack(loo).pow(2).mean(0))


def test_running_statistic_is_the_best_start_minus_its_threshold():
    g = torch.Generator().manual_seed(2)
    log_e = torch.randn(30, generator=g, dtype=F64) * 3  # (T,)
    d = torch.tensor(-math.inf, dtype=F64)
    for t in range(1, 31):
        d = accumulate_evidence(d, log_e[t - 1], evidence_threshold(t, 6, 0.05))
        best = max(
            float(log_e[s - 1 : t].sum()) - evidence_threshold(s, 6, 0.05) for s in range(1, t + 1)
        )
        assert float(d) == pytest.approx(best)
    assert evidence_threshold(1, 6, 0.05) == pytest.approx(math.log(6 * 2 / 0.05))
    # the starts' levels add up to the family-wise level: sum_s a / (K s (s + 1)) -> a / K
    assert sum(
        math.exp(-evidence_threshold(s, 6, 0.05)) for s in range(1, 100_000)
    ) == pytest.approx(0.05 / 6, rel=1e-4)


def test_read_weights_are_confirmed_and_unread_ones_never():
    """Batches from a fixed N(0, I) over 12 weights, costs reading the first four (one strongly,
    three weakly through a shared objective, one through |w|): within 30 batches all four pass
    the level-0.01 threshold, the eight unread weights never do."""
    g = torch.Generator().manual_seed(3)
    n, s, level = 12, 20, 0.01
    d = torch.full((NUM_TESTS, n), -math.inf, dtype=F64)
    past = None
    for t in range(1, 31):
        eps = torch.randn(s, n, generator=g, dtype=F64)
        costs = torch.stack(
            [2 * eps[:, 0] + 0.4 * eps[:, 1] + 0.4 * eps[:, 2], eps[:, 3].abs()], -1
        )  # (S, 2)
        batch = (eps, rank_scores(costs), standard_scores(costs))
        log_e = batch_log_evidence(*batch, *(past or ()))  # (3, N)
        d = accumulate_evidence(d, log_e, evidence_threshold(t, NUM_TESTS * n, level))
        past = (
            batch if past is None else tuple(torch.cat([a, b])[-200:] for a, b in zip(past, batch))
        )
    read = (d >= 0).any(0)
    assert read[:4].all() and not read[4:].any(), d
