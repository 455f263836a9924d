"""The kernel of the environment map and the linear algebra its backends share: squared
distances, the paper's RBF kernel, a Cholesky factorisation with a minimal diagonal jitter, and
the warning issued when an exact solve amplifies round-off into means far outside the data, and
Eq. 7 and 8 solved per query on its own small data set (:func:`local_gp`)."""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

__all__ = ["EnvMapWarning", "sq_dist", "rbf", "posdef_cholesky", "warn_if_amplified", "local_gp"]

# the bound on the mean may exceed the data's range by this factor before the map warns (valid
# data of 2024 environments reach ~1e4; conflicting near-duplicates with zero variance ~1e12)
AMPLIFICATION_LIMIT = 1e6


class EnvMapWarning(RuntimeWarning):
    """An environment map whose predictions are not trustworthy (e.g. conflicting near-duplicate
    environments with variances near 0: the exact GP then amplifies round-off)."""


def sq_dist(a: Tensor, b: Tensor) -> Tensor:
    """Squared Euclidean distances ``(..., P, d), (..., R, d) -> (..., P, R)`` from differences
    (no ``|a|^2 + |b|^2 - 2ab`` cancellation, so duplicates give exactly 0)."""
    return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist") ** 2


def rbf(a: Tensor, b: Tensor, alpha: float) -> Tensor:
    """The paper's kernel ``exp(-alpha ||a - b||^2)``: ``(..., P, d), (..., R, d) ->
    (..., P, R)``."""
    return torch.exp(-alpha * sq_dist(a, b))


def posdef_cholesky(
    a: Tensor, *, scale: Tensor | None = None, max_tries: int = 6
) -> tuple[Tensor, Tensor]:
    """Cholesky factor of a batch of SPD matrices ``(..., P, P)``.

    Exact whenever float64 allows it. A matrix whose factorisation fails (duplicate
    environments with variances near 0 make ``K + Sigma`` singular to round-off) is retried with
    ``jitter = 1e-12, 1e-11, ...`` times its mean diagonal added to the diagonal, for that matrix
    only. ``scale (...,)`` replaces that mean diagonal: a Schur complement ``A22 - L21 L21^T`` of
    a duplicate is ~0, so its jitter must be scaled by ``A22``'s diagonal, not its own. Returns
    ``(L (..., P, P), jitter (...,))`` so the caller can report what was added.
    """
    chol, info = torch.linalg.cholesky_ex(a)  # (..., P, P), (...,)
    jitter = torch.zeros(a.shape[:-2], dtype=a.dtype, device=a.device)  # (...,)
    bad = info != 0  # (...,)
    if not bool(bad.any()):
        return chol, jitter
    if scale is None:
        scale = a.diagonal(dim1=-2, dim2=-1).mean(-1)  # (...,)
    scale = torch.as_tensor(scale, dtype=a.dtype, device=a.device).abs().clamp_min(1e-300)  # (...,)
    eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
    for t in range(max_tries):
        j = torch.where(bad, scale * 10.0 ** (-12 + t), torch.zeros_like(scale))  # (...,)
        c2, info2 = torch.linalg.cholesky_ex(a + j[..., None, None] * eye)
        fixed = bad & (info2 == 0)
        chol = torch.where(fixed[..., None, None], c2, chol)
        jitter = torch.where(fixed, j, jitter)
        bad = bad & ~fixed
        if not bool(bad.any()):
            return chol, jitter
    raise torch.linalg.LinAlgError(
        "K + diag(VAR) is not positive definite even with jitter 1e-7 x its mean diagonal; "
        "check the environments and variances"
    )


def warn_if_amplified(coef: Tensor, MU: Tensor, mu0: Tensor, where: str) -> None:
    """Warn (:class:`EnvMapWarning`) when the cached solve ``coef = A^-1 (MU - mu0)`` ``(M, N)``
    lets the mean leave the data's range by more than ``AMPLIFICATION_LIMIT`` times.

    As ``0 < k(e, e_i) <= 1``, every query's mean obeys ``|mu_n(e) - mu0_n| <= sum_i |coef_in|``;
    that bound is compared with the data's own ``max_i |MU_in - mu0_n|`` (``MU (M, N)``)."""
    bound = coef.abs().sum(0)  # (N,)
    spread = (MU - mu0).abs().amax(0)  # (N,)
    floor = 1e-12 * (mu0.abs() + 1.0)  # (N,) a constant weight's round-off
    bad = bound > AMPLIFICATION_LIMIT * torch.maximum(spread, floor)  # (N,)
    if bool(bad.any()):
        n = int(
            torch.argmax(
                torch.where(bad, bound / torch.maximum(spread, floor), torch.zeros_like(bound))
            )
        )
        warnings.warn(
            f"{where}: the GP mean of weight {n} may reach {float(bound[n]):.3g} from its prior "
            "mean, far "
            f"outside the data (which deviate by at most {float(spread[n]):.3g}): near-duplicate "
            "environments with conflicting means and variances near 0 make K + diag(VAR) "
            "ill-conditioned; give them a variance > 0 or keep one of them",
            EnvMapWarning,
            stacklevel=4,
        )


def local_gp(
    Es: Tensor,
    MUs: Tensor,
    VARs: Tensor,
    Eq: Tensor,
    alpha: float,
    *,
    need_var: bool,
    mu0: Tensor | None = None,
    vbar: Tensor | None = None,
) -> tuple[Tensor, Tensor | None]:
    """Eq. 7 and 8 for each query ``q`` on its own data ``Es[q] (k, d), MUs[q] (k, N), VARs[q] (k,
    N)``:
    one batched ``k x k`` Cholesky per query and weight (each weight has its own noise).

    ``Eq (Q, d)``; ``mu0``, ``vbar`` ``(Q, N)``: the prior mean and average variance, by default
    those of the query's own data. Returns ``(mu (Q, N), var (Q, N) or None)``.
    """
    q, k, n = MUs.shape
    A = rbf(Es, Es, alpha)[:, None].repeat(1, n, 1, 1)  # (Q, N, k, k)
    A.diagonal(dim1=-2, dim2=-1).add_(VARs.transpose(1, 2))  # K + diag(VAR[:, n]) per weight
    L, _ = posdef_cholesky(A)  # (Q, N, k, k)
    mu0 = MUs.mean(1) if mu0 is None else mu0  # (Q, N)
    vbar = VARs.mean(1) if vbar is None else vbar  # (Q, N)
    y = (MUs - mu0[:, None]).transpose(1, 2)[..., None]  # (Q, N, k, 1)
    kq = rbf(Eq[:, None], Es, alpha)[:, 0]  # (Q, k)
    kq4 = kq[:, None, :, None].expand(q, n, k, 1)  # (Q, N, k, 1)
    mu = mu0 + (kq4 * torch.cholesky_solve(y, L)).sum((-1, -2))  # (Q, N)
    if not need_var:
        return mu, None
    v = torch.linalg.solve_triangular(L, kq4, upper=False)  # (Q, N, k, 1)
    return mu, (1.0 - v.square().sum((-1, -2))).clamp_min(0) + vbar  # (Q, N)
