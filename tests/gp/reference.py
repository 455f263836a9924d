"""Test helpers: data and an independent numpy reference of Eq. 7 and 8."""

import numpy as np
import torch

from protorch.gp import BACKENDS as REGISTERED_BACKENDS
from protorch.gp import make_env_map

BACKENDS = sorted(REGISTERED_BACKENDS)  # every registered backend, a new one included

# Options under which a backend solves Eq. 7 and 8 on all of a label's data, for the equation
# checks: the sparse map does while a label has at most `neighbours` environments (beyond, its
# own tests compare it with local_reference below and measure its error against the exact map).
EXACT_OPTIONS = {"sparse": {"neighbours": 4096}}


def exact_map(backend, alpha, **options):
    """An empty map of ``backend`` that computes Eq. 7 and 8 exactly at the contract's sizes."""
    return make_env_map(backend, alpha, **{**EXACT_OPTIONS.get(backend, {}), **options})


def reference_eq78(E, MU, VAR, Q, alpha, *, center=True):
    """Eq. 7 and 8 in float64 numpy, one dense solve per weight (no torch code involved);
    ``center=False``: prior mean 0 instead of the data's average."""
    E, MU, VAR, Q = (np.asarray(x, dtype=np.float64) for x in (E, MU, VAR, Q))
    K = np.exp(-alpha * ((E[:, None, :] - E[None, :, :]) ** 2).sum(-1))  # (M, M)
    kq = np.exp(-alpha * ((Q[:, None, :] - E[None, :, :]) ** 2).sum(-1))  # (Q, M)
    mu = np.empty((Q.shape[0], MU.shape[1]))
    var = np.empty_like(mu)
    for n in range(MU.shape[1]):
        A = K + np.diag(VAR[:, n])
        m0 = MU[:, n].mean() if center else 0.0
        sol = np.linalg.solve(A, np.concatenate([(MU[:, n] - m0)[:, None], kq.T], 1))  # (M, 1 + Q)
        mu[:, n] = m0 + kq @ sol[:, 0]
        var[:, n] = 1.0 + VAR[:, n].mean() - (kq * sol[:, 1:].T).sum(1)
    return mu, var


def make_data(m, n, d=4, *, seed=0, var_lo=1e-2, var_hi=1e-1):
    g = torch.Generator().manual_seed(seed)
    E = torch.rand(m, d, generator=g, dtype=torch.float64) * 2  # (M, d)
    MU = torch.randn(m, n, generator=g, dtype=torch.float64)  # (M, N)
    VAR = var_lo + (var_hi - var_lo) * torch.rand(m, n, generator=g, dtype=torch.float64)  # (M, N)
    return E, MU, VAR


def local_reference(E, MU, VAR, Q, alpha, k):
    """The sparse map without ``nearest_k``: per query, Eq. 7 and 8 solved on its ``k`` nearest
    environments (stable order), with the prior mean and average variance of all the data."""
    E, MU, VAR, Q = (np.asarray(x, dtype=np.float64) for x in (E, MU, VAR, Q))
    mu, var = np.empty((Q.shape[0], MU.shape[1])), np.empty((Q.shape[0], MU.shape[1]))
    m0, v0 = MU.mean(0), VAR.mean(0)
    for q in range(Q.shape[0]):
        near = np.argsort(((E - Q[q]) ** 2).sum(1), kind="stable")[:k]
        # Eq. 7 / 8 on the subset, then swap its own prior mean and average variance for the global
        # ones
        sub_mu, sub_var = reference_eq78(
            E[near], MU[near] - m0, VAR[near], Q[q : q + 1], alpha, center=False
        )
        mu[q], var[q] = m0 + sub_mu[0], sub_var[0] - VAR[near].mean(0) + v0
    return mu, var


def smooth_data(m, n, d=4, *, seed=0, side=0.6):
    """Environments uniform in ``[0, side]^d`` whose weights are smooth functions of them (sines
    of about 25 cm), variances in [1e-4, 1e-2]: like the arm's data, unlike :func:`make_data`'s
    independent means."""
    g = torch.Generator().manual_seed(seed)
    E = side * torch.rand(m, d, generator=g, dtype=torch.float64)  # (M, d)
    freq = 4.0 * torch.randn(8, d, generator=g, dtype=torch.float64)  # (8, d)
    amp = torch.randn(8, n, generator=g, dtype=torch.float64) / 8**0.5  # (8, N)
    MU = (
        torch.sin(E @ freq.T + 6.3 * torch.rand(8, generator=g, dtype=torch.float64)) @ amp
    )  # (M, N)
    VAR = 10 ** (-4 + 2 * torch.rand(m, n, generator=g, dtype=torch.float64))  # (M, N)
    return E, MU, VAR
