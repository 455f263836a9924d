"""RWPO, the relevance-weighted policy optimisation PRO replaces (Ewerton et al., Frontiers in
Neurorobotics 2018, Sec. 5; the authors' MATLAB ``learn_relevances.m``).

The relevance of basis index ``k`` (shared by every DoF) to objective ``o`` is a clipped linear
combination of three fixed functions of ``k``: two sigmoids centred at ``K/3`` and ``2K/3`` and a
constant, ``r_o(k) = clip(theta_o . [rho1(k), rho2(k), 1], 0, 1)``. ``theta_o`` is learned by
reward-weighted regression over a Gaussian (start ``N(0, I)``): each of ``theta_samples`` draws
has ``trajectory_samples`` weight vectors sampled from ``N(mean, diag(var * r_o))`` and scores
``std(c_o) - sum_{o' != o} std(c_o')`` (the relevant objective should vary, the others not),
weighted by ``exp(relevance_beta * score)``. After ``relevance_iters`` iterations the relevance
is the mean clipped ``r_o`` over the last draws divided by its maximum. That learning loop asks
for ``O * theta_samples * trajectory_samples`` rollouts per iteration, which is why RWPO's
relevance costs orders of magnitude more than PRO's one correlation.

After the relevance is learned (once, by default) the updates are PRO's (Eq. 4-6).
"""

from __future__ import annotations

from typing import Generator

import torch
from torch import Tensor

from .functional import stable_rewards
from .pro import PRO

__all__ = ["RWPO", "rwpo_relevance_basis"]


def rwpo_relevance_basis(num_basis: int, *, dtype=torch.float64, device=None) -> Tensor:
    """The three relevance features of basis index ``k = 1..K``: ``(3, K)``."""
    k = torch.arange(1, num_basis + 1, dtype=dtype, device=device)
    rho1 = torch.sigmoid(k - num_basis / 3)
    rho2 = torch.sigmoid(k - 2 * num_basis / 3)
    return torch.stack([rho1, rho2, torch.ones_like(k)])  # (3, K)


class RWPO(PRO):
    """RWPO over ``B`` problems (same contract as :class:`PRO`).

    Args:
        num_objectives: ``O``, required: the relevance learning asks for every objective at once.
        num_basis: ``K`` basis functions per DoF (``N`` must be a multiple); default ``N`` (1 DoF).
        relevance_iters, theta_samples, trajectory_samples, relevance_beta: the learning loop
            (the authors' 50, 200, 50 and 10).
        relevance_every: 0 (default) learns the relevance once, as in the 2018 paper.
        Other arguments: :class:`PRO` / :class:`BaseOptimizer`.

    Example: the first ask of a batch of ``B = 2`` problems, ``N = 3`` weights; costs
    ``(B, S, O)``

    >>> opt = RWPO(torch.zeros(2, 3), torch.ones(2, 3), beta=10.0, num_objectives=1,
    ...      theta_samples=4, trajectory_samples=2)
    >>> w = opt.ask()  # (B, S, N): ``O * theta_samples * trajectory_samples`` first
    >>> w.shape
    torch.Size([2, 8, 3])
    >>> opt.tell((w - 1).pow(2).sum(-1, keepdim=True))  # (B, S, 1)
    """

    features: Tensor  # the relevance basis (a registered buffer, typed for the type checker)

    can_restart = False  # its state is not per problem (global iteration, pooled or external state)
    can_draw_ahead = False  # the relevance learning draws from the generator itself

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor,
        num_objectives: int,
        num_basis: int | None = None,
        relevance_iters: int = 50,
        theta_samples: int = 200,
        trajectory_samples: int = 50,
        relevance_beta: float = 10.0,
        relevance_every: int = 0,
        **kwargs,
    ) -> None:
        kwargs.pop("noise_floor", None)
        super().__init__(
            mean,
            var,
            beta=beta,
            num_objectives=num_objectives,
            relevance_every=relevance_every,
            noise_floor=None,
            **kwargs,
        )
        k = self.num_weights if num_basis is None else int(num_basis)
        if k < 1 or self.num_weights % k != 0:
            raise ValueError(
                f"num_basis = {num_basis} does not divide the {self.num_weights} weights"
            )
        if min(int(relevance_iters), int(theta_samples), int(trajectory_samples)) < 1:
            raise ValueError("relevance_iters, theta_samples and trajectory_samples must be >= 1")
        if int(trajectory_samples) < 2:
            raise ValueError("trajectory_samples must be >= 2 (a std is scored)")
        if not relevance_beta > 0:
            raise ValueError(f"relevance_beta must be > 0, got {relevance_beta}")
        self.num_basis = k
        self.relevance_iters = int(relevance_iters)
        self.theta_samples = int(theta_samples)
        self.trajectory_samples = int(trajectory_samples)
        self.relevance_beta = float(relevance_beta)
        self.register_buffer(
            "features", rwpo_relevance_basis(k, dtype=self.mean.dtype, device=self.mean.device)
        )

    def _relevance(self) -> Generator[Tensor, Tensor, Tensor]:
        b, n, o_count = self.batch_size, self.num_weights, self._objectives
        m, l, dofs = self.theta_samples, self.trajectory_samples, n // self.num_basis
        dt, dev = self.mean.dtype, self.mean.device
        theta_mean = torch.zeros(b, o_count, 3, dtype=dt, device=dev)  # (B, O, 3)
        theta_cov = (
            torch.eye(3, dtype=dt, device=dev).expand(b, o_count, 3, 3).clone()
        )  # (B, O, 3, 3)
        eye3 = torch.eye(3, dtype=dt, device=dev)
        other = 1 - 2 * torch.eye(o_count, dtype=dt, device=dev)  # (O, O): -1 on the diagonal
        for _ in range(self.relevance_iters):
            chol, info = torch.linalg.cholesky_ex(theta_cov + 1e-12 * eye3)  # (B, O, 3, 3)
            if bool((info != 0).any()):  # semi-definite (rewards on few draws): symmetric root
                evals, evecs = torch.linalg.eigh(theta_cov)
                root = evecs * evals.clamp_min(0).sqrt()[..., None, :]  # root @ root^T = theta_cov
                chol = torch.where((info != 0)[..., None, None], root, chol)
            z = torch.randn(b, o_count, m, 3, generator=self.generator, dtype=dt, device=dev)
            theta = theta_mean[:, :, None] + torch.einsum(
                "boij,bomj->bomi", chol, z
            )  # (B, O, M, 3)
            r = (theta @ self.features).clamp(0, 1)  # (B, O, M, K)
            r_full = r.repeat(1, 1, 1, dofs)  # (B, O, M, N): w[d*K + k] has relevance r[k]
            eps = torch.randn(b, o_count, m, l, n, generator=self.generator, dtype=dt, device=dev)
            std = (self.var[:, None, None, :] * r_full).sqrt()  # (B, O, M, N)
            w = self.mean[:, None, None, None, :] + eps * std[:, :, :, None, :]  # (B, O, M, L, N)
            costs = yield w.reshape(b, o_count * m * l, n)  # (B, O*M*L, O)
            spread = costs.reshape(b, o_count, m, l, o_count).std(3)  # (B, O, M, O)
            # score of theta_o: + std of objective o, - std of every other objective
            score = torch.einsum("bomp,op->bom", spread, other).neg()  # (B, O, M)
            rw = stable_rewards(
                -score, self.relevance_beta
            )  # (B, O, M): exp(beta * score), shifted
            rw = rw / rw.sum(-1, keepdim=True)
            new_mean = torch.einsum("bom,bomi->boi", rw, theta)  # (B, O, 3)
            d = (
                theta - theta_mean[:, :, None]
            )  # (B, O, M, 3), around the old mean as the authors do
            theta_cov = torch.einsum("bom,bomi,bomj->boij", rw, d, d)
            theta_cov = 0.5 * (theta_cov + theta_cov.transpose(-1, -2))
            theta_mean = new_mean
        rel = r.mean(2)  # (B, O, K)
        top = rel.amax(-1, keepdim=True)
        rel = torch.where(
            top > 0, rel / torch.where(top > 0, top, torch.ones_like(top)), torch.zeros_like(rel)
        )
        return rel.repeat(1, 1, dofs)  # (B, O, N)
