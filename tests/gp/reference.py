"""Test helpers: data and an independent numpy reference of Eq. 7 and 8."""

import numpy as np
import torch

from protorch.gp import BACKENDS as REGISTERED_BACKENDS

BACKENDS = sorted(REGISTERED_BACKENDS)  # every registered backend, a new one included


def reference_eq78(E, MU, VAR, Q, alpha):
    """Eq. 7 and 8 in float64 numpy, one dense solve per weight (no torch code involved)."""
    E, MU, VAR, Q = (np.asarray(x, dtype=np.float64) for x in (E, MU, VAR, Q))
    K = np.exp(-alpha * ((E[:, None, :] - E[None, :, :]) ** 2).sum(-1))  # (M, M)
    kq = np.exp(-alpha * ((Q[:, None, :] - E[None, :, :]) ** 2).sum(-1))  # (Q, M)
    mu = np.empty((Q.shape[0], MU.shape[1]))
    var = np.empty_like(mu)
    for n in range(MU.shape[1]):
        A = K + np.diag(VAR[:, n])
        m0 = MU[:, n].mean()
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

