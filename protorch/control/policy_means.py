"""The per-call pieces of :class:`~protorch.control.policy.Policy`: every class's mean weights at
one environment (:class:`ClassMeans`, the map's Eq. 7 with cached neighbour-set solves) and the
ProMP basis with its phase derivatives (:func:`basis3`)."""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import Tensor

from ..gp.kernels import posdef_cholesky, rbf, sq_dist

__all__ = ["ClassMeans", "basis3"]


class ClassMeans:
    """Every class's mean weights at one environment, ``env (d,) -> (K, N)`` float64 (module
    docstring, item 1). ``labels (K,)`` names the classes in the rows' order."""

    def __init__(self, env_map, *, cache_size: int = 2048) -> None:
        self.map = env_map
        self.labels = torch.unique(env_map.labels)  # (K,)
        self.alpha = env_map.alpha
        self.cache_size = int(cache_size)
        self.misses = 0
        kw = dict(dtype=torch.float64, device=env_map.device)
        E, MU, VAR, lab = env_map.E.to(**kw), env_map.MU.to(**kw), env_map.VAR.to(**kw), env_map.labels
        k_near = env_map.nearest_k
        groups = getattr(env_map, "groups", None)
        self.mode = "generic"
        if k_near is not None:
            self.mode = "nearest"
            self.rows = [torch.nonzero(lab == g).flatten() for g in self.labels.tolist()]  # per class
            self.E = [E[r].contiguous() for r in self.rows]  # (Mg, d) per class
            self.MU = [MU[r].contiguous() for r in self.rows]  # (Mg, N)
            self.VAR = [VAR[r].contiguous() for r in self.rows]  # (Mg, N)
            self.k = [min(k_near, r.numel()) for r in self.rows]
            self.cache: OrderedDict = OrderedDict()
        elif getattr(env_map, "backend", "") == "torch" and groups is not None:
            self.mode = "exact"
            grp = [groups[str(g)] for g in self.labels.tolist()]
            sizes = [g.m for g in grp]
            self.E_all = torch.cat([g.E[: g.m] for g in grp]).to(**kw)  # (M, d)
            self.coef = torch.cat([g.coef[: g.m] for g in grp]).to(**kw)  # (M, N) A^-1 (MU - mu0), the map's own
            self.mu0 = torch.stack([g.mu0 for g in grp]).to(**kw)  # (K, N)
            self.mask = torch.zeros(len(grp), sum(sizes), **kw)  # (K, M) block diagonal: each class its rows
            start = 0
            for c, m in enumerate(sizes):
                self.mask[c, start:start + m] = 1.0
                start += m

    # ----------------------------------------------------------------- nearest neighbours
    def _neighbours(self, c: int, env: Tensor) -> Tensor:
        """The rows (of class ``c``) of the ``k`` nearest known environments, as the map picks
        them (ties by insertion order), sorted: ``(k,)``."""
        E, k = self.E[c], self.k[c]
        if k == E.shape[0]:
            return torch.arange(k, device=E.device)
        d2 = sq_dist(env[None], E)[0]  # (Mg,) as the map computes them
        if k < E.shape[0]:
            vals, idx = torch.topk(d2, k + 1, largest=False, sorted=True)  # (k + 1,)
            if not bool(vals[k] > vals[k - 1]):  # a tie at the k-th distance: the map's stable order decides
                idx = torch.sort(d2, stable=True).indices
        return torch.sort(idx[:k]).values

    def _solve(self, c: int, idx: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(E_S (k, d), A^-1 (MU_S - mu0) (k, N), mu0 (N,))`` of class ``c``'s neighbour set
        ``idx``, cached (the same solve as :func:`~protorch.gp.kernels.local_gp`)."""
        key = (c, idx.cpu().numpy().tobytes())
        hit = self.cache.get(key)
        if hit is not None:
            self.cache.move_to_end(key)
            return hit
        self.misses += 1
        Es, MUs, VARs = self.E[c][idx], self.MU[c][idx], self.VAR[c][idx]  # (k, d), (k, N), (k, N)
        n = MUs.shape[1]
        A = rbf(Es, Es, self.alpha)[None].repeat(n, 1, 1)  # (N, k, k)
        A.diagonal(dim1=-2, dim2=-1).add_(VARs.T)  # K + diag(VAR[:, n]) per weight
        L, _ = posdef_cholesky(A)  # (N, k, k)
        mu0 = MUs.mean(0)  # (N,)
        coef = torch.cholesky_solve((MUs - mu0).T[..., None], L)[..., 0].T.contiguous()  # (k, N)
        out = (Es, coef, mu0)
        self.cache[key] = out
        if len(self.cache) > self.cache_size:
            self.cache.popitem(last=False)
        return out

    def __call__(self, env: Tensor, classes: list[int] | None = None) -> Tensor:
        """``env (d,)`` float64 -> means ``(K', N)`` of ``classes`` (row indices into
        :attr:`labels`; all by default)."""
        cls = range(self.labels.numel()) if classes is None else classes
        if self.mode == "nearest":
            parts = [self._solve(c, self._neighbours(c, env)) for c in cls]
            if len(parts) == 1:  # views, no copies
                Es, coef, mu0 = (x[None] for x in parts[0])  # (1, k, d), (1, k, N), (1, N)
            elif len({p[0].shape[0] for p in parts}) > 1:  # a class with fewer than k entries: one by one
                return torch.stack([m0 + rbf(env[None], E, self.alpha)[0] @ cf for E, cf, m0 in parts])  # (K', N)
            else:
                Es = torch.stack([p[0] for p in parts])  # (K', k, d)
                coef = torch.stack([p[1] for p in parts])  # (K', k, N)
                mu0 = torch.stack([p[2] for p in parts])  # (K', N)
            kq = rbf(env.expand(Es.shape[0], 1, -1), Es, self.alpha)  # (K', 1, k)
            return mu0 + torch.bmm(kq, coef)[:, 0]  # (K', N) every class in one product
        if self.mode == "exact":
            kq = rbf(env[None], self.E_all, self.alpha)  # (1, M)
            mask = self.mask if classes is None else self.mask[list(cls)]  # (K', M)
            mu0 = self.mu0 if classes is None else self.mu0[list(cls)]
            return mu0 + (mask * kq) @ self.coef  # (K', N) every class in one product
        lab = self.labels[list(cls)]  # (K',)
        return self.map.predict_mean(env.expand(lab.numel(), -1), lab).to(torch.float64)


def basis3(promp, z) -> Tensor:
    """The normalised Gaussian basis and its first two phase derivatives at the phases ``z``
    (a float, a 0-d or a ``(P,)`` tensor): ``(..., 3, K)``
    (:func:`~protorch.control.episodes.basis_derivative_at` for the first; with ``a_k = -(z -
    c_k) / w^2`` and ``s = sum_j g_j a_j``: ``g'' = g' (a - s) - g sum_j g'_j a_j``)."""
    c, w2 = promp.centers.to(torch.float64), promp.width ** 2
    z = torch.as_tensor(z, dtype=torch.float64, device=c.device)
    d = z[..., None] - c  # (..., K)
    b = torch.exp(-0.5 * (d / promp.width) ** 2)  # (..., K) as gaussian_basis
    g = b / b.sum(-1, keepdim=True)
    a = -d / w2
    g1 = g * (a - (g * a).sum(-1, keepdim=True))
    g2 = g1 * (a - (g * a).sum(-1, keepdim=True)) - g * (g1 * a).sum(-1, keepdim=True)
    return torch.stack([g, g1, g2], -2)  # (..., 3, K)
