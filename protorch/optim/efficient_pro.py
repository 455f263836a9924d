"""EPRO: a sample-efficient PRO on the same ask / tell contract (see docs/peers.md).

What it keeps from the paper's PRO (:class:`~protorch.optim.PRO`): reward-weighted regression
of a diagonal Gaussian, a per-weight relevance from correlations between the weights and the
objectives, and the relevance-blended variance of Eq. 6, so a weight that no objective reads
keeps its variance; and, weight by weight and however long it runs, its mean.

What it changes, each measured in benchmarks/studies/peers.py:

1. **One batch per iteration**, ``S`` samples from the full ``N(mean, diag(var))``, shared by
   the relevance, the evidence and the update (the paper asks ``relevance_samples`` probes plus
   ``S`` samples per objective: 500 rollouts per iteration at the defaults, here 20).
2. **Which weights are read is a sequential test** (:mod:`.evidence`): per weight, e-values of
   each batch (the samples standardised by the distribution they were drawn from are exactly
   i.i.d. N(0, 1) for a weight no objective reads, whatever the costs) accumulate into a test
   whose threshold grows with the number of weights and of iterations, so an unread weight of a
   problem is ever declared read with probability at most ``evidence_level`` over the whole
   run. Evidence accumulates for a read weight, not for an unread one.
3. **A read weight** moves its mean to the reward-weighted mean of the batch (Eq. 4) and blends
   its variance with its relevance (Eq. 6). **A weight not (yet) shown to be read** keeps its
   variance exactly; its mean steps ``max(f_n, provisional_step)`` of the way to the
   reward-weighted mean (``f_n`` its relevance, item 4), but only within a trust region around its
   start, ``trust_radius * min(1, sqrt(trust_iterations / t))`` initial stds at iteration ``t``:
   wide while the evidence is still coming in (a read weight helps from the first iteration),
   shrinking the longer the run goes (at the defaults 1 initial std after 45 iterations, 0.13
   after 2,500), so an unread weight ends near its start however long the run.
4. **Relevance from the update samples**, pooled over the last ``pool`` batches, each batch in
   its own units (the samples standardised, the costs centred on the batch's mean):
   ``rho_o(n) = max(|rho(z_n, o)|, |rho(z_n^2, o)|)`` (the second term sees a cost V-shaped
   around the mean, a distance at its minimum, whose linear correlation is 0), under noise floors
   from the pool's effective size ``P_eff = S (sum_b v_b)^2 / sum_b v_b^2`` (``v_b`` the variance
   of batch ``b``'s centred costs of objective ``o``): ``f_o(n)`` is ``rho_o(n)`` where it reaches
   ``noise_floor / sqrt(P_eff)``, divided by the row's maximum, and ``g_o(n)`` is ``f_o(n)`` where
   ``rho_o(n)`` also reaches ``variance_floor / sqrt(P_eff)``: the variance's blend of a read
   weight is ``g_n = max_o g_o(n)``.
5. **Reward temperature per iteration**: ``R_i = exp(-beta_t (c_i - min c))`` on the total cost
   ``c = sum_o c_o * cost_o`` with ``beta_t`` set (bisection in log space) so the normalised
   rewards have an effective sample size ``(sum R)^2 / sum R^2 = ess * S``; a fixed ``beta`` can
   be given instead.

The update, ``read`` the weights shown to be read, ``m0`` and ``s0`` the start's mean and std::

    target = sum_i R_i w_i / sum_i R_i
    mean'  = target                                                   (read)
           = clip(mean + max(f, c) (target - mean), m0 -+ radius_t s0) (not read; c =
           provisional_step)
    var'   = (1 - g) * var + g * sum_i R_i (w_i - mean)^2 / sum_i R_i  (read; not read: var)

``evidence_level=None`` turns the test and the trust region off: every weight then counts as
read for the variance's blend and moves its mean by ``f_n = max_o f_o(n)``,
``mean' = mean + f (target - mean)`` (the relevance alone decides).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Generator, NamedTuple

import torch
from torch import Tensor

from .base import BaseOptimizer
from .evidence import (
    NUM_TESTS,
    accumulate_evidence,
    batch_log_evidence,
    evidence_threshold,
    rank_scores,
    standard_scores,
)
from .functional import abs_correlation, normalize_rows, stable_rewards

__all__ = [
    "EPRO",
    "ess_temperature",
    "curvature_relevance",
    "gated_relevance",
    "effective_pool_size",
    "standardize_batch",
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
    unit = (
        shifted / torch.where(flat, torch.ones_like(scale), scale)[..., None]
    )  # (..., S) in [0, 1]
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


def curvature_relevance(
    w: Tensor, costs: Tensor, center: Tensor, noise_floor: float | None
) -> Tensor:
    """``f (..., O, N)``: per objective, the larger of ``|rho(w_n, o)|`` and
    ``|rho((w_n - center_n)^2, o)|`` over the samples ``w (..., P, N)``, ``costs (..., P, O)``,
    under the noise floor ``z / sqrt(P)``, normalised by the row's maximum: :func:`gated_relevance`
    with every pooled sample counted and no variance gate."""
    p = torch.full(
        costs.shape[:-2] + costs.shape[-1:],
        float(w.shape[-2]),
        dtype=torch.float64,
        device=w.device,
    )
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
    return torch.where(
        sq > 0, s * total.pow(2) / torch.where(sq > 0, sq, torch.ones_like(sq)), full
    )


def gated_relevance(
    w: Tensor,
    costs: Tensor,
    center: Tensor,
    p_eff: Tensor,
    noise_floor: float | None,
    variance_floor: float | None,
    curvature: bool = True,
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
    mean_ok = (
        rho >= noise_floor / root
        if noise_floor is not None
        else torch.ones_like(rho, dtype=torch.bool)
    )
    f = normalize_rows(torch.where(mean_ok, rho, torch.zeros_like(rho)))
    var_ok = (
        rho >= variance_floor / root if variance_floor is not None else torch.ones_like(mean_ok)
    )
    return f, torch.where(var_ok, f, torch.zeros_like(f))


class EPRO(BaseOptimizer):
    """Sample-efficient PRO over ``B`` problems at once (see the module docstring).

    Args:
        beta: ``None`` (default) sets the reward temperature every iteration for ``ess``; a
            float or ``(B,)`` fixes it on the total cost instead, as the paper's PRO does.
        ess: target effective sample size of the rewards, as a fraction of ``num_samples``.
        pool: the relevance and the evidence read the samples of the last ``pool`` iterations.
        noise_floor: ``z`` of the relevance's noise floor, ``|rho| < z / sqrt(P_eff)`` counts as 0
            (default 2.5; with ``evidence_level=None`` it gates the mean); ``None`` counts every
            correlation, as the paper's formula is written.
        variance_floor: ``z`` of the variance's floor (default 3.5): a read weight's variance is
            blended only where its ``|rho|`` reaches ``variance_floor / sqrt(P_eff)``; ``None``
            applies ``noise_floor`` to the variance too.
        evidence_level: family-wise level ``a`` of the read-weight test (:mod:`.evidence`),
            default 0.001: an unread weight of a problem is ever declared read with probability at
            most ``a``. ``None`` turns the test and the trust region off.
        trust_radius, trust_iterations: the trust region of a weight not shown to be read is
            ``trust_radius * min(1, sqrt(trust_iterations / t))`` initial stds around its start
            mean at iteration ``t`` (defaults 3.0 and 5).
        provisional_step: such a weight's mean steps ``max(f_n, provisional_step)`` of the way to
            the reward-weighted mean (default 0.75; 0: its relevance alone, 1: all the way).
        curvature: also correlate ``(w_n - mean_n)^2`` with the costs (default); ``False``: the
            linear Pearson relevance alone, as the paper's PRO.
        standardize: pool each batch's samples in its own units (default); ``False`` pools the
            raw samples and costs for the relevance (an unread weight then correlates with the
            costs' drift; the evidence always reads the standardised samples).
        objective_weights: ``(O,)``, default all ones: how objectives combine into the total cost.
        Other arguments: :class:`BaseOptimizer` (``num_samples`` defaults to 20 here).

    Attributes: ``read (B, N)`` the weights shown to be read, ``evidence (B, 3, N)`` the running
    statistic of each test (read once ``>= 0``), ``relevance`` / ``variance_relevance``
    ``(B, O, N)`` the last ``f`` and ``g``.

    Example: the ask / tell loop on ``||w - 1||^2`` (unbatched: ``(S, N)`` asked, ``(S,)`` told)

    >>> opt = EPRO(torch.zeros(3), torch.ones(3), num_samples=10, seed=0)
    >>> while not opt.stop():
    ...     w = opt.ask()  # (S, N)
    ...     opt.tell((w - 1).pow(2).sum(-1))  # (S,): one objective
    >>> bool((opt.result().mean - 1).abs().max() < 0.1)
    True
    """

    # the registered buffers (typed for the type checker)
    start_mean: Tensor  # (B, N)
    start_std: Tensor  # (B, N)
    evidence: Tensor  # (B, tests, N)
    read: Tensor  # (B, N) bool

    can_restart = False  # its state is not per problem (global iteration, pooled or external state)

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor | None = None,
        ess: float = 0.2,
        pool: int = 10,
        noise_floor: float | None = 2.5,
        variance_floor: float | None = 3.5,
        evidence_level: float | None = 0.001,
        trust_radius: float = 3.0,
        trust_iterations: int = 5,
        provisional_step: float = 0.75,
        curvature: bool = True,
        standardize: bool = True,
        objective_weights=None,
        num_samples: int = 20,
        **kwargs,
    ) -> None:
        super().__init__(
            mean, var, beta=1.0 if beta is None else beta, num_samples=num_samples, **kwargs
        )
        if not 0 < ess <= 1:
            raise ValueError(f"ess must be in (0, 1], got {ess}")
        if int(pool) < 1:
            raise ValueError(f"pool must be >= 1, got {pool}")
        for key, z in (("noise_floor", noise_floor), ("variance_floor", variance_floor)):
            if z is not None and not z >= 0:
                raise ValueError(f"{key} must be >= 0 or None, got {z}")
        if evidence_level is not None and not 0 < evidence_level < 1:
            raise ValueError(f"evidence_level must be in (0, 1) or None, got {evidence_level}")
        if not trust_radius >= 0 or int(trust_iterations) < 1:
            raise ValueError(
                f"need trust_radius >= 0 and trust_iterations >= 1, got {trust_radius}, "
                f"{trust_iterations}"
            )
        if not 0 <= provisional_step <= 1:
            raise ValueError(f"provisional_step must be in [0, 1], got {provisional_step}")
        if self.num_samples < 3:
            raise ValueError(f"num_samples must be >= 3 for a correlation, got {self.num_samples}")
        self.adaptive = beta is None
        self.ess = float(ess)
        self.pool = int(pool)
        self.noise_floor = noise_floor
        self.variance_floor = variance_floor
        self.evidence_level = None if evidence_level is None else float(evidence_level)
        self.trust_radius = float(trust_radius)
        self.trust_iterations = int(trust_iterations)
        self.provisional_step = float(provisional_step)
        self.curvature = bool(curvature)
        self.standardize = bool(standardize)
        self._set_objective_weights(objective_weights)
        self._pool: deque[Batch] = deque(maxlen=self.pool)
        self.register_buffer("start_mean", self.mean.clone())  # (B, N)
        self.register_buffer("start_std", self.var.sqrt())  # (B, N)
        self.register_buffer(
            "evidence",
            torch.full(
                (self.batch_size, NUM_TESTS, self.num_weights),
                -math.inf,
                dtype=self.mean.dtype,
                device=self.mean.device,
            ),
        )  # (B, 3, N)
        self.register_buffer(
            "read", torch.zeros_like(self.converged[:, None]).expand(-1, self.num_weights).clone()
        )
        self.relevance: Tensor | None = None  # (B, O, N), the mean's
        self.variance_relevance: Tensor | None = None  # (B, O, N)
        self.history["relevance"] = []

    def _gate(self, batch: "Batch") -> tuple[Tensor, Tensor]:
        """The running evidence ``(B, 3, N)`` and the read weights ``(B, N)`` after ``batch``."""
        if self.evidence_level is None:
            return self.evidence, torch.ones_like(self.read)
        past = list(self._pool)
        if past:
            log_e = batch_log_evidence(
                batch.z,
                batch.ranks,
                batch.scores,
                *(torch.cat([getattr(b, k) for b in past], 1) for k in ("z", "ranks", "scores")),
            )  # (B, 3, N)
        else:
            log_e = batch_log_evidence(batch.z, batch.ranks, batch.scores)
        h = evidence_threshold(
            self.iteration + 1, NUM_TESTS * self.num_weights, self.evidence_level
        )
        evidence = accumulate_evidence(self.evidence, log_e, h)  # (B, 3, N)
        return evidence, self.read | (evidence >= 0).any(1)

    def _relevance(self, batches: list["Batch"]) -> tuple[Tensor, Tensor]:
        """``(f, g)``, each ``(B, O, N)``, from the pooled batches (module docstring, item 4)."""
        if self.standardize:
            pooled_w = torch.cat([b.z for b in batches], 1)  # (B, P, N)
            center = torch.zeros_like(self.mean)  # (B, N): the sampling mean, in standard units
        else:
            pooled_w = torch.cat([b.w for b in batches], 1)
            center = self.mean
        centred = (
            [b.costs - b.costs.mean(-2, keepdim=True) for b in batches]
            if self.standardize
            else [b.costs for b in batches]
        )
        p_eff = effective_pool_size(
            [b.costs - b.costs.mean(-2, keepdim=True) for b in batches]
        )  # (B, O)
        return gated_relevance(
            pooled_w,
            torch.cat(centred, 1),
            center,
            p_eff,
            self.noise_floor,
            self.variance_floor,
            self.curvature,
        )

    def _iteration(self) -> Generator[Tensor, Tensor, None]:
        w = self._sample(self.var, self.num_samples)  # (B, S, N)
        self.asked_objective = None
        costs = yield w  # (B, S, O)
        self._record_cost(slice(None), costs)
        z = standardize_batch(
            w, self.mean, self.var
        )  # (B, S, N), i.i.d. N(0, 1) for an unread weight
        batch = Batch(w, costs, z, rank_scores(costs), standard_scores(costs))
        evidence, read = self._gate(batch)  # (B, 3, N), (B, N)
        kept = (
            list(self._pool)[1 - self.pool :] if self.pool > 1 else []
        )  # the pool once this batch joins it
        relevance, variance_relevance = self._relevance([*kept, batch])
        f = relevance.amax(1)  # (B, N)
        g = (variance_relevance * read[:, None]).amax(
            1
        )  # (B, N): only a read weight's variance moves
        total = self._total_cost(costs)  # (B, S)
        beta = ess_temperature(total, self.ess) if self.adaptive else self.beta  # (B,)
        rewards = stable_rewards(total, beta, dim=-1)  # (B, S)
        r = (rewards / rewards.sum(-1, keepdim=True)).to(w.dtype)  # (B, S)
        target = torch.einsum("bs,bsn->bn", r, w)  # (B, N)
        spread = torch.einsum("bs,bsn->bn", r, (w - self.mean[:, None]) ** 2)  # (B, N)
        if self.evidence_level is None:
            new_mean = self.mean + f * (target - self.mean)
        else:
            radius = self.trust_radius * min(
                1.0, math.sqrt(self.trust_iterations / (self.iteration + 1))
            )
            lo, hi = (
                self.start_mean - radius * self.start_std,
                self.start_mean + radius * self.start_std,
            )
            prov = self.mean + f.clamp_min(self.provisional_step) * (target - self.mean)  # (B, N)
            new_mean = torch.where(read, target, torch.minimum(torch.maximum(prov, lo), hi))
        new_var = (1 - g) * self.var + g * spread
        flat = (total.amax(-1) <= total.amin(-1))[
            :, None
        ]  # (B, 1): equal costs say nothing, nothing moves
        new_mean, new_var = (
            torch.where(flat, self.mean, new_mean),
            torch.where(flat, self.var, new_var),
        )
        # commit (nothing above changed the optimiser's state)
        self._pool.append(batch)
        active = ~self.converged[:, None]  # (B, 1)
        self.evidence.copy_(torch.where(active[..., None], evidence, self.evidence))
        self.read.copy_(torch.where(active, read, self.read))
        self.relevance, self.variance_relevance = relevance, variance_relevance
        self.history["relevance"].append(relevance.clone())
        self._commit(new_mean, new_var)


class Batch(NamedTuple):
    """One iteration's samples ``w (B, S, N)``, costs ``(B, S, O)``, standardised samples ``z``
    and the costs as rank scores and standard scores ``(B, S, O)``."""

    w: Tensor
    costs: Tensor
    z: Tensor
    ranks: Tensor
    scores: Tensor
