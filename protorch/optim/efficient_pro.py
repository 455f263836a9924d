"""EPRO: a sample-efficient PRO on the same ask / tell contract (see docs/peers.md).

What it keeps from the paper's PRO (:class:`~protorch.optim.PRO`): reward-weighted regression
of a diagonal Gaussian, a per-weight relevance ``f_n`` in [0, 1] from correlations between the
weights and the objectives, and the relevance-blended update of Eq. 6, so a weight that no
objective reads (relevance under the noise floor) keeps its mean and its variance.

What it changes, each measured in benchmarks/peers.py:

1. **One batch per iteration**, ``S`` samples from the full ``N(mean, diag(var))``, shared by
   the relevance and the update (the paper asks ``relevance_samples`` probes plus ``S`` samples
   per objective: 500 rollouts per iteration at the defaults, here 20).
2. **Relevance from the update samples**, pooled over the last ``pool`` batches, each batch in
   its own units (the samples standardised by the distribution they were drawn from, the costs
   centred on the batch's mean), so an unread weight's pooled samples are i.i.d. N(0, 1) and
   cannot correlate with the costs' drift from batch to batch:
   ``rho_o(n) = max(|rho(z_n, o)|, |rho(z_n^2, o)|)``. The second term sees a weight whose cost
   is V-shaped around the mean (a distance at its minimum): its linear correlation is 0 there,
   which is what freezes the paper's PRO a little short of the optimum.
3. **Two noise floors from the pool's effective size.** The pooled batches' cost spreads shrink
   as the run converges, so the early ones dominate each correlation and the pool counts as
   ``P_eff = S (sum_b v_b)^2 / sum_b v_b^2`` samples, not ``P`` (``v_b`` the variance of batch
   ``b``'s centred costs of objective ``o``). A correlation counts for the *mean* when it exceeds
   ``noise_floor / sqrt(P_eff)`` and for the *variance* only when it also exceeds
   ``variance_floor / sqrt(P_eff)``: a weakly read weight moves its mean on weak evidence, while
   a chance correlation of an unread weight, which is rarely far above the floor, cannot shrink
   its variance. ``f_o(n)`` is ``rho_o(n)`` under the mean's floor divided by the row's maximum;
   the variance's relevance is ``f_o(n)`` where ``rho_o(n)`` also passes the variance's floor,
   else 0. The update reads ``f_n = max_o f_o(n)`` (and the variance's likewise).
4. **Reward temperature per iteration**: ``R_i = exp(-beta_t (c_i - min c))`` on the total cost
   ``c = sum_o c_o * cost_o`` with ``beta_t`` set (bisection in log space) so the normalised
   rewards have an effective sample size ``(sum R)^2 / sum R^2 = ess * S``; a fixed ``beta`` can
   be given instead. Costs of any scale then give the same selection pressure.

The update (Eq. 4-6 with the relevance gating the mean as well, since the samples of an
irrelevant weight are not held at the mean here)::

    mean' = mean + f * (sum_i R_i w_i / sum_i R_i - mean)
    var'  = (1 - g) * var + g * sum_i R_i (w_i - mean)^2 / sum_i R_i      (g <= f: the variance's relevance)
"""

from __future__ import annotations

from collections import deque
from typing import Generator

import torch
from torch import Tensor

from .base import BaseOptimizer
from .functional import abs_correlation, normalize_rows, stable_rewards

__all__ = [
    "EPRO", "ess_temperature", "curvature_relevance", "gated_relevance", "effective_pool_size", "standardize_batch",
]


def standardize_batch(w: Tensor, mean: Tensor, var: Tensor) -> Tensor:
    """``(w - mean) / sqrt(var)`` for samples ``w (..., S, N)`` drawn from ``N(mean, diag(var))``,
    ``mean, var (..., N)`` (a zero variance gives 0). Pooled over iterations, the samples of a
    weight no objective reads are then i.i.d. N(0, 1) whatever its mean and variance did, so they
    cannot correlate with the costs' drift from one iteration to the next."""
    std = var.sqrt().unsqueeze(-2)  # (..., 1, N)
    return (w - mean.unsqueeze(-2)) / torch.where(std > 0, std, torch.ones_like(std))


def ess_temperature(costs: Tensor, ess: float, *, steps: int = 40) -> Tensor:
    """``beta (...)`` for ``costs (..., S)`` such that ``exp(-beta (c - min c))`` has an effective
    sample size of ``ess * S`` (to bisection precision). Constant costs give ``beta = 1``
    (every reward is 1 then, whatever beta)."""
    if not 0 < ess <= 1:
        raise ValueError(f"ess must be in (0, 1], got {ess}")
    shifted = costs - costs.amin(-1, keepdim=True)  # (..., S)
    scale = shifted.amax(-1)  # (...)
    flat = scale <= 0
    unit = shifted / torch.where(flat, torch.ones_like(scale), scale)[..., None]  # (..., S) in [0, 1]
    target = ess * costs.shape[-1]
    lo = torch.full_like(scale, -6.0)  # log10 of beta * scale
    hi = torch.full_like(scale, 6.0)
    for _ in range(steps):  # the ESS falls monotonically as beta grows
        mid = (lo + hi) / 2
        r = torch.exp(-(10.0**mid)[..., None] * unit)  # (..., S)
        n_eff = r.sum(-1) ** 2 / r.pow(2).sum(-1)  # (...)
        too_sharp = n_eff < target
        hi = torch.where(too_sharp, mid, hi)
        lo = torch.where(too_sharp, lo, mid)
    beta = 10.0 ** ((lo + hi) / 2) / torch.where(flat, torch.ones_like(scale), scale)
    return torch.where(flat, torch.ones_like(beta), beta)


def curvature_relevance(w: Tensor, costs: Tensor, center: Tensor, noise_floor: float | None) -> Tensor:
    """``f (..., O, N)``: per objective, the larger of ``|rho(w_n, o)|`` and
    ``|rho((w_n - center_n)^2, o)|`` over the samples ``w (..., P, N)``, ``costs (..., P, O)``,
    under the noise floor ``z / sqrt(P)``, normalised by the row's maximum: :func:`gated_relevance`
    with every pooled sample counted and no variance gate."""
    p = torch.full(costs.shape[:-2] + costs.shape[-1:], float(w.shape[-2]), dtype=torch.float64, device=w.device)
    return gated_relevance(w, costs, center, p, noise_floor, None)[0]


def effective_pool_size(batch_costs: list[Tensor]) -> Tensor:
    """``P_eff (..., O)`` of pooled batches ``batch_costs[b] (..., S, O)``: ``S (sum_b v_b)^2 /
    sum_b v_b^2`` with ``v_b`` batch ``b``'s variance of each objective (about the batch's mean).
    Equal spreads give ``P = S * batches``; one batch far wider than the rest gives about ``S``.
    An objective constant in every batch gives ``P``."""
    v = torch.stack([c.var(-2, unbiased=False) for c in batch_costs], 0)  # (K, ..., O)
    total = v.sum(0)  # (..., O)
    s = batch_costs[0].shape[-2]
    full = torch.full_like(total, float(s * len(batch_costs)))
    sq = v.pow(2).sum(0)
    return torch.where(sq > 0, s * total.pow(2) / torch.where(sq > 0, sq, torch.ones_like(sq)), full)


def gated_relevance(
    w: Tensor, costs: Tensor, center: Tensor, p_eff: Tensor, noise_floor: float | None,
    variance_floor: float | None, curvature: bool = True,
) -> tuple[Tensor, Tensor]:
    """``(f, g)``, each ``(..., O, N)``: the mean's and the variance's relevance from the pooled
    samples ``w (..., P, N)``, ``costs (..., P, O)`` (see the module): ``rho`` the larger of
    ``|rho(w_n, o)|`` and (``curvature``) ``|rho((w_n - center_n)^2, o)|``; ``f`` = ``rho`` where
    it reaches ``noise_floor / sqrt(p_eff)`` (``p_eff (..., O)``), divided by the row's maximum;
    ``g`` = ``f`` where ``rho`` also reaches ``variance_floor / sqrt(p_eff)``, else 0. A floor of
    ``None`` gates nothing."""
    n = w.shape[-1]
    feats = torch.cat([w, (w - center.unsqueeze(-2)) ** 2], -1) if curvature else w  # (..., P, F)
    rho = abs_correlation(feats, costs)  # (..., O, F)
    if curvature:
        rho = torch.maximum(rho[..., :n], rho[..., n:])  # (..., O, N)
    root = p_eff.sqrt().unsqueeze(-1)  # (..., O, 1)
    mean_ok = rho >= noise_floor / root if noise_floor is not None else torch.ones_like(rho, dtype=torch.bool)
    f = normalize_rows(torch.where(mean_ok, rho, torch.zeros_like(rho)))
    var_ok = rho >= variance_floor / root if variance_floor is not None else torch.ones_like(mean_ok)
    return f, torch.where(var_ok, f, torch.zeros_like(f))

class EPRO(BaseOptimizer):
    """Sample-efficient PRO over ``B`` problems at once (see the module docstring).

    Args:
        beta: ``None`` (default) sets the reward temperature every iteration for ``ess``; a
            float or ``(B,)`` fixes it on the total cost instead, as the paper's PRO does.
        ess: target effective sample size of the rewards, as a fraction of ``num_samples``.
        pool: the relevance reads the samples of the last ``pool`` iterations (``>= 1``).
        noise_floor: ``z`` of the mean's noise floor, ``|rho| < z / sqrt(P_eff)`` counts as 0
            (default 2.5); ``None`` counts every correlation, as the paper's formula is written.
        variance_floor: ``z`` of the variance's floor (default 3.5): a weight's variance is
            updated only where its ``|rho|`` reaches ``variance_floor / sqrt(P_eff)``; ``None``
            applies the mean's relevance to the variance too.
        curvature: also correlate ``(w_n - mean_n)^2`` with the costs (default); ``False``: the
            linear Pearson relevance alone, as the paper's PRO.
        standardize: pool each batch in its own units (default): the samples as
            ``(w - mean) / std`` of the distribution they were drawn from, the costs minus the
            batch's mean cost; ``False`` pools the raw samples and costs (measured in
            docs/peers.md: an unread weight then correlates with the costs' drift).
        objective_weights: ``(O,)``, default all ones: how objectives combine into the total cost.
        Other arguments: :class:`BaseOptimizer` (``num_samples`` defaults to 20 here).
    """

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor | None = None,
        ess: float = 0.25,
        pool: int = 10,
        noise_floor: float | None = 2.5,
        variance_floor: float | None = 3.5,
        curvature: bool = True,
        standardize: bool = True,
        objective_weights=None,
        num_samples: int = 20,
        **kwargs,
    ) -> None:
        super().__init__(mean, var, beta=1.0 if beta is None else beta, num_samples=num_samples, **kwargs)
        if not 0 < ess <= 1:
            raise ValueError(f"ess must be in (0, 1], got {ess}")
        if int(pool) < 1:
            raise ValueError(f"pool must be >= 1, got {pool}")
        for key, z in (("noise_floor", noise_floor), ("variance_floor", variance_floor)):
            if z is not None and not z >= 0:
                raise ValueError(f"{key} must be >= 0 or None, got {z}")
        if self.num_samples < 3:
            raise ValueError(f"num_samples must be >= 3 for a correlation, got {self.num_samples}")
        self.adaptive = beta is None
        self.ess = float(ess)
        self.pool = int(pool)
        self.noise_floor = noise_floor
        self.variance_floor = variance_floor
        self.curvature = bool(curvature)
        self.standardize = bool(standardize)
        self._set_objective_weights(objective_weights)
        self._pool: deque[tuple[Tensor, Tensor]] = deque(maxlen=self.pool)
        self.relevance: Tensor | None = None  # (B, O, N), the mean's
        self.variance_relevance: Tensor | None = None  # (B, O, N)
        self.history["relevance"] = []

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        w = self._sample(self.var, self.num_samples)  # (B, S, N)
        self.asked_objective = None
        costs = yield w  # (B, S, O)
        self._record_cost(slice(None), costs)
        if self.standardize:
            z = standardize_batch(w, self.mean, self.var)  # (B, S, N), N(0, 1) for an unread weight
            self._pool.append((z, costs - costs.mean(-2, keepdim=True)))  # each batch's costs centred
            center = torch.zeros_like(self.mean)  # (B, N): the sampling mean, in standard units
        else:
            self._pool.append((w, costs))
            center = self.mean
        pooled_w = torch.cat([p[0] for p in self._pool], 1)  # (B, P, N)
        pooled_c = torch.cat([p[1] for p in self._pool], 1)  # (B, P, O)
        p_eff = effective_pool_size([p[1] for p in self._pool])  # (B, O)
        self.relevance, self.variance_relevance = gated_relevance(
            pooled_w, pooled_c, center, p_eff, self.noise_floor, self.variance_floor, self.curvature)  # (B, O, N) each
        self.history["relevance"].append(self.relevance.clone())
        f, g = self.relevance.amax(1), self.variance_relevance.amax(1)  # (B, N), g <= f
        total = self._total_cost(costs)  # (B, S)
        beta = ess_temperature(total, self.ess) if self.adaptive else self.beta  # (B,)
        rewards = stable_rewards(total, beta, dim=-1)  # (B, S)
        r = (rewards / rewards.sum(-1, keepdim=True)).to(w.dtype)  # (B, S)
        target = torch.einsum("bs,bsn->bn", r, w)  # (B, N)
        spread = torch.einsum("bs,bsn->bn", r, (w - self.mean[:, None]) ** 2)  # (B, N)
        new_mean = self.mean + f * (target - self.mean)
        new_var = (1 - g) * self.var + g * spread
        self._apply(new_mean, new_var)
