"""Sequential evidence that an objective reads a weight: EPRO's gate (see docs/peers.md).

EPRO samples ``w = mean + sqrt(var) * eps`` with ``eps ~ N(0, I)``. If no objective reads weight
``n``, the costs of a batch do not depend on ``eps_n``: given the batch's costs, the other
weights' samples and everything before the batch, ``eps_n`` is exactly i.i.d. ``N(0, 1)``. The
null hypothesis "weight ``n`` is unread" thus fixes the conditional law of the data, and any
density ``q`` of ``eps_n`` given those, chosen before ``eps_n`` is seen, gives an *e-value*
``prod_i q(eps_in) / phi(eps_in)`` with expectation 1 under the null; the product of the
batches' e-values is a test martingale, which by Ville's inequality ever reaches ``1 / a`` with
probability at most ``a``, however long the run.

Three alternatives ``q`` are tested for every weight (:func:`batch_log_evidence`):

- **linear**: ``eps_n`` shifts with the costs, ``eps_n ~ N(x beta_n, 1)``, ``x`` the batch's
  cost ranks as normal scores (:func:`rank_scores`: scale and outliers do not matter), ``beta_n``
  under a ``N(0, prior^2)`` prior updated on the previous batches (the Bayesian predictive
  density, an e-value from the first batch on);
- **scale**: ``eps_n``'s spread changes with the costs (a cost V-shaped around the mean reads
  ``|eps_n|``, not its sign), ``eps_n ~ N(0, exp(x gamma_n))``, ``gamma_n`` half the
  least-squares fit of ``eps_n^2 - 1`` on ``x`` over the previous batches;
- **surrogate**: a linear model of every objective's standardised costs on all the weights,
  fitted on the previous batches (:func:`fit_surrogate`), explains away the other weights: the
  density of ``eps_n`` given the costs and the other samples under that model (a Gaussian), mixed
  half and half with ``phi`` so a wrong model costs little. Many weights read by one objective
  each carry a small correlation with its cost; what is left once the others are explained is
  mostly ``eps_n``'s own part, which is where this test draws its power.

Evidence that starts late counts too (a weight may be read only once the mean reaches where it
matters): with ``h_s = log(K s (s + 1) / a)`` the threshold of evidence that starts at iteration
``s`` (``K`` = 3 alternatives x ``N`` weights), ``D_t = max(D_{t-1}, -h_t) + log e_t`` is the
largest ``log e_{s..t} - h_s`` over the starts ``s <= t`` (:func:`accumulate_evidence`), and a
weight counts as *read* once ``D_t >= 0`` for some alternative. The probability that an unread
weight of a problem is ever declared read is at most ``sum_s a / (s (s + 1)) = a`` (Ville's
inequality for each start, a union bound over the starts, the alternatives and the weights).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "rank_scores",
    "standard_scores",
    "fit_surrogate",
    "batch_log_evidence",
    "evidence_threshold",
    "accumulate_evidence",
    "NUM_TESTS",
]

NUM_TESTS = 3  # alternatives per weight: linear, scale, surrogate


def rank_scores(costs: Tensor) -> Tensor:
    """``(..., S, O)`` -> ``(..., S, O)``: each objective's costs replaced by the normal quantiles
    of
    their ranks within the batch (ties share their average rank), scaled to mean 0 and variance 1
    over the batch. A constant objective gives 0."""
    s = costs.shape[-2]
    below = (costs.unsqueeze(-3) < costs.unsqueeze(-2)).sum(
        -2
    )  # (..., S, O): samples with a lower cost
    equal = (costs.unsqueeze(-3) == costs.unsqueeze(-2)).sum(-2)  # (..., S, O), itself included
    u = (below + equal / 2) / s  # (..., S, O), in (0, 1)
    return standard_scores(math.sqrt(2.0) * torch.erfinv((2 * u - 1).to(costs.dtype)))


def standard_scores(costs: Tensor) -> Tensor:
    """``(..., S, O)``: each objective minus the batch's mean, over the batch's std (a constant
    objective gives 0)."""
    c = costs - costs.mean(-2, keepdim=True)
    sd = c.pow(2).mean(-2, keepdim=True).sqrt()  # (..., 1, O)
    flat = sd <= 1e-12 * costs.abs().amax(-2, keepdim=True).clamp_min(1e-300)
    return torch.where(flat, torch.zeros_like(c), c / torch.where(flat, torch.ones_like(sd), sd))


def _ridge(x: Tensor, y: Tensor, ridge: float) -> tuple[Tensor, Tensor]:
    """``(x^T x + ridge I)^-1`` ``(..., F, F)`` and the ridge solution ``(..., F, K)`` for
    ``x (..., P, F)``, ``y (..., P, K)``."""
    a = x.transpose(-1, -2) @ x + ridge * torch.eye(x.shape[-1], dtype=x.dtype, device=x.device)
    a_inv = torch.linalg.inv(a)
    return a_inv, a_inv @ (x.transpose(-1, -2) @ y)


def fit_surrogate(eps: Tensor, y: Tensor, ridge: float = 5.0) -> tuple[Tensor, Tensor]:
    """A linear model ``y ~ eps b + noise`` of the costs' standard scores ``y (..., P, O)`` on the
    standardised samples ``eps (..., P, N)``: ``(b (..., N, O), noise (..., O))``, ``b`` the ridge
    solution and ``noise`` each objective's mean squared leave-one-out residual, an honest estimate
    even where ``P < N`` and the fit interpolates."""
    p, n = eps.shape[-2], eps.shape[-1]
    if p < n:  # kernel form: (P, P)
        k_inv = torch.linalg.inv(
            eps @ eps.transpose(-1, -2) + ridge * torch.eye(p, dtype=eps.dtype, device=eps.device)
        )
        alpha = k_inv @ y  # (..., P, O)
        loo = alpha / torch.diagonal(k_inv, dim1=-2, dim2=-1).unsqueeze(-1)  # (..., P, O)
        return eps.transpose(-1, -2) @ alpha, loo.pow(2).mean(-2)
    a_inv, coef = _ridge(eps, y, ridge)  # (..., N, N), (..., N, O)
    hat = ((eps @ a_inv) * eps).sum(-1, keepdim=True)  # (..., P, 1): leverages
    loo = (y - eps @ coef) / (1 - hat)
    return coef, loo.pow(2).mean(-2)


def _linear(
    x: Tensor, eps: Tensor, past_x: Tensor | None, past_eps: Tensor | None, prior: float
) -> tuple[Tensor, Tensor]:
    """The linear and the scale alternative's log e-values ``(..., N)`` each."""
    s, o = x.shape[-2], x.shape[-1]
    ridge = 1.0 / prior**2
    if past_x is None or past_eps is None:
        a_inv = (
            torch.eye(o, dtype=x.dtype, device=x.device).expand(*x.shape[:-2], o, o) / ridge
        )  # (..., O, O)
        beta = torch.zeros(
            *x.shape[:-2], o, eps.shape[-1], dtype=x.dtype, device=x.device
        )  # (..., O, N)
        gamma = beta
    else:
        a_inv, beta = _ridge(
            past_x, past_eps, ridge
        )  # the posterior's covariance and mean (..., O, N)
        gamma = (
            0.5 * _ridge(past_x, past_eps.pow(2) - 1, ridge)[1]
        )  # (..., O, N): half the fit, a cautious bet
    # linear: the batch's eps_n ~ N(x beta_n, I + x A^-1 x^T), the Bayesian predictive density
    cov = torch.eye(s, dtype=x.dtype, device=x.device) + x @ a_inv @ x.transpose(
        -1, -2
    )  # (..., S, S)
    chol = torch.linalg.cholesky(cov)
    white = torch.linalg.solve_triangular(chol, eps - x @ beta, upper=False)  # (..., S, N)
    logdet = 2 * torch.diagonal(chol, dim1=-2, dim2=-1).log().sum(-1)  # (...)
    linear = (
        -0.5 * logdet.unsqueeze(-1) - 0.5 * white.pow(2).sum(-2) + 0.5 * eps.pow(2).sum(-2)
    )  # (..., N)
    # scale: eps_n ~ N(0, exp(eta)), eta = x gamma_n (clipped: the variance at most e^2-fold either
    # way)
    eta = (x @ gamma).clamp(-2.0, 2.0)  # (..., S, N)
    scale = (-0.5 * eta - 0.5 * eps.pow(2) * torch.expm1(-eta)).sum(-2)  # (..., N)
    return linear, scale


def _surrogate(
    y: Tensor, eps: Tensor, coef: Tensor, noise: Tensor, hedge: float = 0.5, min_noise: float = 0.05
) -> Tensor:
    """The surrogate alternative's log e-value ``(..., N)``: per sample and weight, the density of
    ``eps_n`` given the cost scores ``y (..., S, O)`` and the other weights' samples under
    ``y ~ eps b + N(0, noise)`` (prior N(0, 1) times the likelihood of the partial residuals
    ``y - sum_{m != n} eps_m b_m``: Gaussian), as ``hedge q / phi + 1 - hedge``; the noise is
    floored at ``min_noise`` (the model is never trusted to be exact)."""
    s2 = noise.clamp_min(min_noise).unsqueeze(-2)  # (..., 1, O)
    partial = (y - eps @ coef).unsqueeze(-2) + eps.unsqueeze(-1) * coef.unsqueeze(
        -3
    )  # (..., S, N, O)
    prec = 1 + (coef.pow(2) / s2).sum(-1).unsqueeze(
        -2
    )  # (..., 1, N): the posterior precision of eps_n
    mu = (coef.unsqueeze(-3) * partial / s2.unsqueeze(-2)).sum(-1) / prec  # (..., S, N)
    log_q = (
        0.5 * prec.log() - 0.5 * prec * (eps - mu).pow(2) + 0.5 * eps.pow(2)
    )  # (..., S, N): log q / phi
    return torch.log1p(hedge * torch.expm1(log_q.clamp(max=50.0))).sum(-2)  # (..., N)


def batch_log_evidence(
    eps: Tensor,
    ranks: Tensor,
    scores: Tensor,
    past_eps: Tensor | None = None,
    past_ranks: Tensor | None = None,
    past_scores: Tensor | None = None,
    *,
    prior: float = 0.5,
    ridge: float = 5.0,
) -> Tensor:
    """``log e (..., 3, N)`` of one batch for the linear, the scale and the surrogate alternative.

    Args:
        eps: ``(..., S, N)`` the batch's standardised samples ``(w - mean) / sqrt(var)``.
        ranks: ``(..., S, O)`` its costs as :func:`rank_scores`.
        scores: ``(..., S, O)`` its costs as :func:`standard_scores`.
        past_eps, past_ranks, past_scores: ``(..., P, .)``, the previous batches the alternatives
            are fitted on (``None``: none yet; the linear alternative is then its prior's mixture,
            the other two are ``phi`` itself, ``log e = 0``).
        prior: std of the linear alternative's prior on each coefficient.
        ridge: the surrogate's ridge penalty.

    Each alternative is a density of ``eps_n`` fixed before ``eps`` is seen, so under the null
    (``eps_n`` i.i.d. N(0, 1) given the costs and the other samples) each e-value has expectation 1.
    """
    past = (past_eps, past_ranks, past_scores)
    if any(p is None for p in past) and any(p is not None for p in past):
        raise ValueError(
            "past_eps, past_ranks and past_scores must be given together or not at all"
        )
    linear, scale = _linear(ranks, eps, past_ranks, past_eps, prior)
    if past_eps is None or past_scores is None:
        surrogate = torch.zeros_like(linear)
    else:
        coef, noise = fit_surrogate(past_eps, past_scores, ridge)
        surrogate = _surrogate(scores, eps, coef, noise)
    return torch.stack([linear, scale, surrogate], -2)  # (..., 3, N)


def evidence_threshold(iteration: int, num_tests: int, level: float) -> float:
    """``h_s = log(K s (s + 1) / a)``: the log e-value that evidence starting at iteration ``s``
    (1-based) must reach, ``K`` tests in all, family-wise level ``a`` over every start."""
    return math.log(num_tests * iteration * (iteration + 1) / level)


def accumulate_evidence(running: Tensor, log_e: Tensor, threshold: float) -> Tensor:
    """``D_t = max(D_{t-1}, -h_t) + log e_t`` (elementwise): the largest evidence over the starts
    ``s <= t`` minus that start's threshold; a test rejects (the weight is read) once ``D_t >= 0``.
    Start from ``running = -inf``."""
    return torch.maximum(running, torch.full_like(running, -threshold)) + log_e
