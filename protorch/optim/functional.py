"""The pure functional core of PRO (Ewerton et al., IROS 2019, Sec. III A-B).

No state, no randomness: each function maps tensors to tensors and accepts any leading batch
dimensions ``...``. ``S`` samples, ``N`` weights, ``O`` objectives.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from ..checks import check_positive, check_tensor

__all__ = [
    "stable_rewards",
    "abs_correlation",
    "normalize_rows",
    "pearson_relevance",
    "pro_update",
    "noise_floor_threshold",
]


def _beta_tensor(beta, ref: Tensor) -> Tensor:
    beta_t = torch.as_tensor(beta, dtype=ref.dtype, device=ref.device)
    check_positive(beta_t, "beta")
    return beta_t


def stable_rewards(costs: Tensor, beta, dim: int = -1) -> Tensor:
    """``exp(-beta * (cost - min cost))`` along ``dim``: the best sample gets reward 1.

    Shifting by the minimum leaves the normalised weights ``R_i / sum_j R_j`` of Eq. 4-5 unchanged
    and keeps them finite for any cost scale. ``beta`` is a float or a tensor that broadcasts
    against ``costs`` with ``dim`` removed (one beta per problem).
    """
    costs = check_tensor(costs, "costs")
    costs = costs if costs.is_floating_point() else costs.to(torch.float64)  # exp of ints: float64
    beta_t = _beta_tensor(beta, costs)
    if beta_t.ndim > 0:
        per_problem = costs.shape[: dim % costs.ndim] + costs.shape[dim % costs.ndim + 1 :]
        try:  # numpy's rule: torch.broadcast_shapes imports sympy on first use (~1.5 s per process)
            np.broadcast_shapes(tuple(beta_t.shape), tuple(per_problem))
        except ValueError:
            raise ValueError(
                f"beta of shape {tuple(beta_t.shape)} does not broadcast against the costs' "
                "problems "
                f"{tuple(per_problem)} (costs {tuple(costs.shape)} without the sample dim)"
            ) from None
    return _shifted_rewards(costs, beta_t, dim)


def _shifted_rewards(costs: Tensor, beta: Tensor, dim: int) -> Tensor:
    """:func:`stable_rewards` without its checks: ``beta`` a tensor of the costs' dtype."""
    beta = beta.unsqueeze(dim) if beta.ndim > 0 else beta
    shifted = costs - costs.amin(dim, keepdim=True)
    return torch.exp(-beta * shifted)


def noise_floor_threshold(num_samples: int, z: float) -> float:
    """|rho| below ``z / sqrt(S)`` is indistinguishable from an uncorrelated pair (to ~z sigma)."""
    return float(z) / math.sqrt(num_samples)


def _is_constant(centered: Tensor, raw: Tensor, std: Tensor) -> Tensor:
    """Entries whose sample std is at rounding level relative to their magnitude."""
    eps = torch.finfo(raw.dtype).eps
    scale = raw.abs().amax(-2)
    return std <= 64 * eps * scale.clamp_min(torch.finfo(raw.dtype).tiny)


def _pow2_scale(x: Tensor) -> Tensor:
    """``2^e (..., 1, C)`` with ``max_s |x| = m 2^e``, ``m in [0.5, 1)`` (1 for a zero column)."""
    _, e = torch.frexp(x.abs().amax(-2, keepdim=True))
    return torch.ldexp(torch.ones_like(x[..., :1, :]), e)


def abs_correlation(w: Tensor, costs: Tensor) -> Tensor:
    """``|Pearson rho(w_n, o)| (..., O, N)`` of samples ``w (..., S, N)`` and ``costs (..., S, O)``,
    unnormalised; a constant weight or a constant objective gives 0 (not NaN)."""
    w = check_tensor(w, "w", ndim_min=2)
    costs = check_tensor(costs, "costs", ndim_min=2)
    if w.shape[:-1] != costs.shape[:-1]:
        raise ValueError(
            f"w (..., S, N) and costs (..., S, O) must agree on (..., S): got {tuple(w.shape)} "
            f"and {tuple(costs.shape)}"
        )
    num_samples = w.shape[-2]
    if num_samples < 3:
        raise ValueError(f"a Pearson correlation needs at least 3 samples, got S = {num_samples}")
    dtype = torch.promote_types(w.dtype, costs.dtype)
    if not dtype.is_floating_point:
        dtype = torch.get_default_dtype()
    w, costs = w.to(dtype), costs.to(dtype)
    # rho is shift-invariant; shifting each weight and each objective by its first sample (exact
    # for nearby values) makes a constant one exactly 0 and judges "constant" against the samples'
    # spread, not the magnitude (in float32, probes of std 3e-3 around |mean| >= ~400, or costs of
    # spread 3e-3 around 1000, would read as constant)
    w = w - w[..., :1, :]
    costs = costs - costs[..., :1, :]
    wc = w - w.mean(-2, keepdim=True)  # (..., S, N)
    cc = costs - costs.mean(-2, keepdim=True)  # (..., S, O)
    const_w = _is_constant(wc, w, wc.pow(2).mean(-2).sqrt())  # (..., N)
    const_c = _is_constant(cc, costs, cc.pow(2).mean(-2).sqrt())  # (..., O)
    # rho is scale-invariant: dividing by a power of two near each column's largest |value| is
    # exact, and keeps the squares finite for values near the dtype's maximum
    wc, cc = wc / _pow2_scale(wc), cc / _pow2_scale(cc)
    sw = wc.pow(2).mean(-2).sqrt()  # (..., N)
    sc = cc.pow(2).mean(-2).sqrt()  # (..., O)
    cov = torch.einsum("...sn,...so->...on", wc, cc) / num_samples  # (..., O, N)
    denom = sc[..., :, None] * sw[..., None, :]  # (..., O, N)
    dead = const_c[..., :, None] | const_w[..., None, :]  # (..., O, N)
    rho = torch.where(
        dead, torch.zeros_like(cov), cov / torch.where(dead, torch.ones_like(denom), denom)
    )
    return rho.abs().clamp(max=1.0)  # (..., O, N)


def normalize_rows(rho: Tensor) -> Tensor:
    """Each row ``(..., O, N)`` divided by its maximum; an all-zero row stays 0."""
    top = rho.amax(-1, keepdim=True)  # (..., O, 1)
    return torch.where(
        top > 0, rho / torch.where(top > 0, top, torch.ones_like(top)), torch.zeros_like(rho)
    )


def pearson_relevance(w: Tensor, costs: Tensor, *, noise_floor: float | None = None) -> Tensor:
    """Relevance of each weight to each objective: normalised ``|Pearson rho(w_n, o)|``.

    Args:
        w: ``(..., S, N)`` weight samples (the authors draw them around the mean with a small
            uniform variance).
        costs: ``(..., S, O)`` objective values of those samples.
        noise_floor: optional ``z``. An estimated correlation of two unrelated variables is not 0
            but noise of size ``1/sqrt(S)``; with ``z`` set, ``|rho| < z / sqrt(S)`` counts as 0
            before normalising. ``None`` is the paper's formula as written. Without
            a floor the irrelevant variance slowly collapses in the Fig. 3 toy.

    Returns:
        ``(..., O, N)`` in [0, 1], each objective's row divided by its maximum. A constant weight,
        a constant objective, or an objective with no correlation above the floor gives 0.
    """
    if noise_floor is not None and noise_floor < 0:
        raise ValueError(f"noise_floor must be >= 0, got {noise_floor}")
    rho = abs_correlation(w, costs)  # (..., O, N)
    if noise_floor is not None:
        rho = torch.where(
            rho < noise_floor_threshold(w.shape[-2], noise_floor), torch.zeros_like(rho), rho
        )
    return normalize_rows(rho)


def pro_update(
    mean: Tensor,
    var: Tensor,
    samples: Tensor,
    costs: Tensor,
    relevance: Tensor,
    beta,
    *,
    validate: bool = True,
) -> tuple[Tensor, Tensor]:
    """One objective's PRO step (Eq. 4, 5 around the old mean, and 6).

    Args:
        mean: ``(..., N)`` current mean.
        var: ``(..., N)`` current diagonal variance.
        samples: ``(..., S, N)`` weights drawn from ``N(mean, diag(var * relevance))``.
        costs: ``(..., S)`` this objective's cost of each sample (``(..., S, 1)`` accepted).
        relevance: ``(..., N)`` in [0, 1] for this objective.
        beta: reward temperature > 0: a float or ``(...)`` (one per problem).
        validate: check the inputs (finite, shapes, ``var >= 0``, relevance in [0, 1], ``beta > 0``)
            before any work. ``False`` skips the checks for a caller whose inputs hold by
            construction (the optimisers' own steps, where they cost as much as the update);
            the inputs must then be floating tensors of one dtype, ``beta`` one too.

    Returns:
        ``(new_mean (..., N), new_var (..., N))`` with
        ``new_mean = sum_i R_i w_i / sum_i R_i``,
        ``C_n = sum_i R_i (w_in - mean_n)^2 / sum_i R_i`` and
        ``new_var = (1 - f_n) var_n + f_n C_n``, ``R_i = exp(-beta cost_i)``.
    """
    if validate:
        mean, var, samples, costs, relevance = _checked_update(mean, var, samples, costs, relevance)
        rewards = stable_rewards(costs, beta, dim=-1)  # (..., S)
    else:
        if costs.ndim == samples.ndim and costs.shape[-1] == 1:
            costs = costs[..., 0]
        rewards = _shifted_rewards(costs, beta, -1)  # (..., S)
    weights = rewards / rewards.sum(-1, keepdim=True)  # (..., S), sums to 1, max weight > 0
    weights = weights.to(samples.dtype)
    new_mean = torch.einsum("...s,...sn->...n", weights, samples)  # (..., N)
    spread = torch.einsum(
        "...s,...sn->...n", weights, (samples - mean.unsqueeze(-2)) ** 2
    )  # (..., N)
    new_var = (1 - relevance) * var + relevance * spread  # (..., N)
    return new_mean, new_var


def _checked_update(
    mean, var, samples, costs, relevance
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """:func:`pro_update`'s inputs checked (an error naming the problem) and promoted to floats."""
    mean = check_tensor(mean, "mean", ndim_min=1)
    var = check_tensor(var, "var", ndim_min=1)
    samples = check_tensor(samples, "samples", ndim_min=2)
    costs = check_tensor(costs, "costs", ndim_min=1)
    relevance = check_tensor(relevance, "relevance", ndim_min=1)
    if not (mean.is_floating_point() and var.is_floating_point() and samples.is_floating_point()):
        # integer (or bool) inputs are promoted, never truncated: float64 unless one is floating
        dtype = next(
            (x.dtype for x in (samples, mean, var) if x.is_floating_point()), torch.float64
        )
        mean, var, samples = mean.to(dtype), var.to(dtype), samples.to(dtype)
    relevance = relevance if relevance.is_floating_point() else relevance.to(samples.dtype)
    costs = costs if costs.is_floating_point() else costs.to(samples.dtype)
    if costs.ndim == samples.ndim and costs.shape[-1] == 1:
        costs = costs[..., 0]
    batch, n = mean.shape[:-1], mean.shape[-1]
    if var.shape != mean.shape or relevance.shape != mean.shape:
        raise ValueError(
            f"mean, var and relevance must share a shape (..., N): got {tuple(mean.shape)}, "
            f"{tuple(var.shape)}, {tuple(relevance.shape)}"
        )
    if samples.shape[:-2] != batch or samples.shape[-1] != n:
        raise ValueError(
            f"samples must be (..., S, {n}) with ... = {tuple(batch)}, got {tuple(samples.shape)}"
        )
    if costs.shape != samples.shape[:-1]:
        raise ValueError(
            f"costs must be (..., S) = {tuple(samples.shape[:-1])}, got {tuple(costs.shape)}"
        )
    if bool((var < 0).any()):
        raise ValueError("var must be >= 0")
    if bool(((relevance < 0) | (relevance > 1)).any()):
        raise ValueError("relevance must lie in [0, 1]")
    return mean, var, samples, costs, relevance
