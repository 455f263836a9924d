"""Backend ``"torch"``: Eq. 7 and 8 in closed form with incrementally extended Cholesky factors.

Per label group and weight ``n`` it keeps the lower Cholesky factor ``L_n`` of
``A_n = K + diag(VAR[:, n])`` inside a preallocated ``(N, cap, cap)`` buffer. Adding ``B`` points
extends every factor in place (``L21 = (L^-1 a12)^T``, ``L22 = chol(A22 - L21 L21^T)``):
``O(N M^2 B)``, no refactorisation. It also keeps the forward-substituted vectors
``z_y = L^-1 MU`` and ``z_1 = L^-1 1`` (extended in ``O(N M B)``) and the cached solve
``coef = A^-1 (MU - mu0) = L^-T (z_y - mu0 z_1)`` (one back-substitution, ``O(N M^2)``), so the
prior mean ``mu0`` may change with every add and the mean of one query costs ``O(M d + M N)``.

Variance: exact (one forward substitution per weight, ``O(N M^2)`` per query), or with
``approx_var=True`` a Nystroem approximation: a pivoted Cholesky of the kernel matrix picks
``r`` pivot environments until the largest residual kernel variance is below ``var_tol`` (at most
``var_rank`` pivots), ``k_e ~ F f_e`` with ``F (M, r)`` the pivoted factor and
``f_e = R^-1 k(S, e)``; then ``k_e^T A_n^-1 k_e ~ f_e^T H_n f_e`` with ``H_n = F^T A_n^-1 F``
``(N, r, r)``, cached (in float32 unless ``var_dtype="float64"``). A query then costs ``O(r d + N
r^2)``. The approximation is exact when
``k_e`` lies in the span of the pivot columns; its error is printed by ``benchmarks/gp.py``.
The cache is rebuilt (``O(N M^2 r)``) at the first approximate query after a change.

The triangular solves run on strided views of the capacity buffer, block by block
(``torch.linalg.solve_triangular`` would copy the whole ``M x M`` view each call).
"""

from __future__ import annotations

from typing import Any, cast

import torch
from torch import Tensor, nn

from .base import EnvMap
from .kernels import local_gp, posdef_cholesky, rbf, warn_if_amplified

__all__ = ["TorchEnvMap"]

_VAR_DTYPES = {"float32": torch.float32, "float64": torch.float64}


def _solve_lower(L: Tensor, m: int, b: Tensor, block: int) -> Tensor:
    """``X = L[:m, :m]^-1 b`` for a lower factor stored in a larger buffer ``L (cap, cap)``;
    ``b (m, R) -> X (m, R)``, blocked so the big products are matmuls on strided views."""
    x = torch.empty_like(b)  # (m, R)
    for s in range(0, m, block):
        e = min(s + block, m)
        r = b[s:e]  # (bs, R)
        if s:
            r = r - L[s:e, :s] @ x[:s]  # (bs, R)
        x[s:e] = torch.linalg.solve_triangular(L[s:e, s:e], r, upper=False)
    return x


def _solve_lower_t(L: Tensor, m: int, b: Tensor, block: int) -> Tensor:
    """``X = L[:m, :m]^-T b`` (back-substitution), ``b (m, R) -> X (m, R)``."""
    x = torch.empty_like(b)  # (m, R)
    starts = list(range(0, m, block))
    for s in reversed(starts):
        e = min(s + block, m)
        r = b[s:e]  # (bs, R)
        if e < m:
            r = r - L[e:m, s:e].T @ x[e:m]  # (bs, R)
        x[s:e] = torch.linalg.solve_triangular(L[s:e, s:e].T, r, upper=True)
    return x


class _CholGroup(nn.Module):
    """Exact GPs (one per weight) of one label group, with factors extended in place."""

    # the registered buffers (typed for the type checker; nn.Module.__getattr__ returns them)
    L: Tensor  # (N, cap, cap)
    E: Tensor  # (cap, d)
    zy: Tensor  # (N, cap)
    z1: Tensor  # (N, cap)
    coef: Tensor  # (cap, N)
    mu_sum: Tensor  # (N,)
    var_sum: Tensor  # (N,)
    jitter: Tensor  # (N,)
    nys_S: Tensor | None  # (r, d)
    nys_R: Tensor | None  # (r, r)
    nys_H: Tensor | None  # (N, r, r)

    def __init__(
        self,
        alpha: float,
        d: int,
        n: int,
        *,
        capacity: int,
        block: int,
        growth: float,
        var_rank: int,
        var_tol: float,
        var_dtype,
        dtype,
        device,
    ) -> None:
        super().__init__()
        self.alpha, self.block, self.growth = alpha, block, growth
        self.var_rank, self.var_tol, self.var_dtype = var_rank, var_tol, var_dtype
        self.m = 0
        kw = dict(dtype=dtype, device=device)
        cap = max(int(capacity), 1)
        self.register_buffer("L", torch.zeros(n, cap, cap, **kw))  # (N, cap, cap)
        self.register_buffer("E", torch.zeros(cap, d, **kw))  # (cap, d)
        self.register_buffer("zy", torch.zeros(n, cap, **kw))  # (N, cap)  L^-1 MU
        self.register_buffer("z1", torch.zeros(n, cap, **kw))  # (N, cap)  L^-1 1
        self.register_buffer("coef", torch.zeros(cap, n, **kw))  # (cap, N) A^-1 (MU - mu0)
        self.register_buffer("mu_sum", torch.zeros(n, **kw))  # (N,)
        self.register_buffer("var_sum", torch.zeros(n, **kw))  # (N,)
        self.register_buffer("jitter", torch.zeros(n, **kw))  # (N,) largest jitter ever added
        # Nystroem variance cache, None while stale
        self.register_buffer("nys_S", None)  # (r, d) pivot environments
        self.register_buffer("nys_R", None)  # (r, r) lower Cholesky of K_SS
        self.register_buffer("nys_H", None)  # (N, r, r)

    @property
    def capacity(self) -> int:
        return self.L.shape[1]

    @property
    def mu0(self) -> Tensor:
        return self.mu_sum / self.m  # (N,)

    @property
    def vbar(self) -> Tensor:
        return self.var_sum / self.m  # (N,)

    def _ensure_capacity(self, need: int) -> None:
        if need <= self.capacity:
            return
        m, cap = self.m, max(need, int(self.growth * self.capacity) + 1)
        n, d = self.L.shape[0], self.E.shape[1]
        kw: dict[str, Any] = dict(dtype=self.L.dtype, device=self.L.device)
        L = torch.zeros(n, cap, cap, **kw)  # (N, cap, cap)
        L[:, :m, :m] = self.L[:, :m, :m]
        E = torch.zeros(cap, d, **kw)  # (cap, d)
        E[:m] = self.E[:m]
        zy, z1 = torch.zeros(n, cap, **kw), torch.zeros(n, cap, **kw)  # (N, cap)
        zy[:, :m], z1[:, :m] = self.zy[:, :m], self.z1[:, :m]
        self.L, self.E, self.zy, self.z1 = L, E, zy, z1
        self.coef = torch.zeros(cap, n, **kw)  # (cap, N), recomputed by extend()

    def extend(self, E: Tensor, MU: Tensor, VAR: Tensor) -> bool:
        """Append ``E (B, d), MU (B, N), VAR (B, N)``: ``O(N M^2 B)``. Returns whether a factor of
        the new rows needed jitter (then only they carry it, unlike a refit's whole diagonal)."""
        b, m, n = E.shape[0], self.m, MU.shape[1]
        self._ensure_capacity(m + b)
        L = self.L
        k22 = rbf(E, E, self.alpha)  # (B, B)
        k12 = rbf(self.E[:m], E, self.alpha) if m else E.new_zeros(0, b)  # (m, B)
        eye = torch.eye(b, dtype=E.dtype, device=E.device)
        new_jit = torch.zeros(n, dtype=E.dtype, device=E.device)  # (N,)
        for i in range(n):  # one weight at a time keeps the memory at O(M^2)
            s = k22 + eye * VAR[:, i]  # (B, B)
            if m:
                x = _solve_lower(L[i], m, k12, self.block)  # (m, B)
                s = s - x.T @ x  # (B, B) Schur complement
                L[i, m : m + b, :m] = x.T
            # jitter scaled by A22's diagonal: the Schur complement of a duplicate is ~0
            l22, jit = posdef_cholesky(s, scale=(k22.diagonal() + VAR[:, i]).mean())  # (B, B)
            L[i, m : m + b, m : m + b] = l22
            new_jit[i] = jit
        # forward vectors of the new rows: z_new = L22^-1 (rhs - L21 z_old)
        rhs = torch.stack([MU.T, torch.ones_like(MU.T)], -1)  # (N, B, 2)
        if m:
            z_old = torch.stack([self.zy[:, :m], self.z1[:, :m]], -1)  # (N, m, 2)
            rhs = rhs - L[:, m : m + b, :m] @ z_old  # (N, B, 2)
        z_new = torch.linalg.solve_triangular(
            L[:, m : m + b, m : m + b], rhs, upper=False
        )  # (N, B, 2)
        self.zy[:, m : m + b], self.z1[:, m : m + b] = z_new[..., 0], z_new[..., 1]
        self.E[m : m + b] = E
        self.m = m + b
        self.mu_sum += MU.sum(0)
        self.var_sum += VAR.sum(0)
        self.jitter = torch.maximum(self.jitter, new_jit)
        self._update_coef()
        self.nys_S = self.nys_R = self.nys_H = None
        return bool((new_jit > 0).any())

    def _update_coef(self) -> None:
        m, mu0 = self.m, self.mu0  # (N,)
        for i in range(self.L.shape[0]):
            z = (self.zy[i, :m] - mu0[i] * self.z1[i, :m])[:, None]  # (m, 1)
            self.coef[:m, i] = _solve_lower_t(self.L[i], m, z, self.block)[:, 0]

    # ----------------------------------------------------------- predict
    def mean(self, Eq: Tensor) -> Tensor:
        kq = rbf(Eq, self.E[: self.m], self.alpha)  # (Q, M)
        return self.mu0 + kq @ self.coef[: self.m]  # (Q, N)

    def var_exact(self, Eq: Tensor) -> Tensor:
        m = self.m
        kq = rbf(self.E[:m], Eq, self.alpha)  # (M, Q)
        quad = torch.stack(
            [
                _solve_lower(self.L[i], m, kq, self.block).square().sum(0)
                for i in range(self.L.shape[0])
            ],
            -1,
        )  # (Q, N)
        return (1.0 - quad).clamp_min(0) + self.vbar  # (Q, N)

    def var_approx(self, Eq: Tensor) -> Tensor:
        S, R, H = self._nystrom()  # (r, d), (r, r), (N, r, r)
        kS = rbf(S, Eq, self.alpha)  # (r, Q)
        f = torch.linalg.solve_triangular(R, kS, upper=False).to(H.dtype)  # (r, Q)
        n, r = H.shape[:2]
        hf = (H.reshape(n * r, r) @ f).reshape(n, r, -1)  # (N, r, Q): one big matmul
        quad = (hf * f).sum(1).T.to(Eq.dtype)  # (Q, N)
        return (1.0 - quad).clamp_min(0) + self.vbar  # (Q, N)

    def _nystrom(self) -> tuple[Tensor, Tensor, Tensor]:
        """The Nystroem cache ``(S (r, d), R (r, r), H (N, r, r))``, built when stale."""
        if self.nys_S is None or self.nys_R is None or self.nys_H is None:
            self._build_nystrom()
        return cast(Tensor, self.nys_S), cast(Tensor, self.nys_R), cast(Tensor, self.nys_H)

    def _build_nystrom(self) -> None:
        """Pivoted Cholesky of K (``F F^T ~ K``), then ``H_n = (L_n^-1 F)^T (L_n^-1 F)``."""
        m, E = self.m, self.E[: self.m]
        rmax = min(self.var_rank, m)
        F = torch.zeros(m, rmax, dtype=E.dtype, device=E.device)  # (M, r)
        resid = torch.ones(m, dtype=E.dtype, device=E.device)  # (M,) k(e, e) = 1
        piv: list[int] = []
        for j in range(rmax):
            i = int(torch.argmax(resid))
            if float(resid[i]) <= self.var_tol:
                break
            col = rbf(E, E[i : i + 1], self.alpha)[:, 0] - F[:, :j] @ F[i, :j]  # (M,)
            F[:, j] = col / resid[i].sqrt()
            resid = (resid - F[:, j].square()).clamp_min(0)
            resid[i] = 0
            piv.append(i)
        F = F[:, : len(piv)]  # (M, r)
        self.nys_S = E[piv].clone()  # (r, d)
        self.nys_R = F[piv].clone()  # (r, r), lower triangular: chol(K_SS)
        self.nys_H = torch.stack(
            [
                (lambda w: w.T @ w)(_solve_lower(self.L[i], m, F, self.block))
                for i in range(self.L.shape[0])
            ]
        ).to(self.var_dtype)  # (N, r, r)


class TorchEnvMap(EnvMap):
    """Closed-form backend (module docstring). Extra options:

    Args:
        capacity: points preallocated per label group (grown by ``growth`` when exceeded).
        block: block size of the triangular solves on the capacity buffer.
        var_rank, var_tol: Nystroem rank limit and pivot tolerance of ``approx_var=True``.
        var_dtype: ``"float32"`` (default) or ``"float64"``: dtype of the Nystroem cache ``H``
            ``(N, r, r)``. A query reads all of it (36 MB at N = 70, r = 256 in float64), so
            float32 halves the approximate variance's latency; its rounding (~1e-7 absolute on a
            variance) is far below the Nystroem error itself. ``"float64"`` makes the
            approximation exact (to round-off) whenever the pivots span the kernel columns.

    Example: fit ``M = 6`` environments ``(M, d)`` with their weight means and variances
    ``(M, N)``, predict at two

    >>> g = torch.Generator().manual_seed(0)
    >>> E, MU = torch.rand(6, 2, generator=g), torch.rand(6, 4, generator=g)
    >>> env_map = TorchEnvMap(alpha=1.0).fit(E, MU, torch.full((6, 4), 0.1))
    >>> mu, var = env_map.predict(E[:2])  # (Q, N) each
    >>> mu.shape, bool((var > 0).all())
    (torch.Size([2, 4]), True)
    """

    backend = "torch"

    def __init__(
        self,
        alpha: float,
        *,
        nearest_k: int | None = None,
        capacity: int = 64,
        growth: float = 1.5,
        block: int = 256,
        var_rank: int = 256,
        var_tol: float = 1e-10,
        var_dtype: str = "float32",
        dtype: torch.dtype = torch.float64,
        device=None,
    ) -> None:
        super().__init__(alpha, nearest_k=nearest_k, dtype=dtype, device=device)
        for name, v in (("capacity", capacity), ("block", block), ("var_rank", var_rank)):
            if isinstance(v, bool) or int(v) != v or int(v) < 1:
                raise ValueError(f"{name} must be an int >= 1, got {v!r}")
        if not float(growth) > 1.0:
            raise ValueError(f"growth must be > 1, got {growth}")
        if not float(var_tol) >= 0.0:
            raise ValueError(f"var_tol must be >= 0, got {var_tol}")
        self.capacity, self.growth, self.block = int(capacity), float(growth), int(block)
        if var_dtype not in _VAR_DTYPES:
            raise ValueError(f"var_dtype must be one of {sorted(_VAR_DTYPES)}, got {var_dtype!r}")
        self.var_rank, self.var_tol, self.var_dtype = int(var_rank), float(var_tol), var_dtype
        self.groups = nn.ModuleDict()

    def options(self) -> dict:
        return {
            **super().options(),
            "capacity": self.capacity,
            "growth": self.growth,
            "block": self.block,
            "var_rank": self.var_rank,
            "var_tol": self.var_tol,
            "var_dtype": self.var_dtype,
        }

    @property
    def jitter(self) -> dict[int, Tensor]:
        """Per label, the largest diagonal jitter ``(N,)`` the factorisation needed (0 = exact)."""
        return {int(k): cast(_CholGroup, g).jitter for k, g in self.groups.items()}

    def _reset_groups(self) -> None:
        self.groups = nn.ModuleDict()

    def _has_group(self, g: int) -> bool:
        return str(g) in self.groups

    def _group_fit(self, g, E, MU, VAR) -> None:
        grp = _CholGroup(
            self.alpha,
            E.shape[1],
            MU.shape[1],
            capacity=max(self.capacity, E.shape[0]),
            block=self.block,
            growth=self.growth,
            var_rank=self.var_rank,
            var_tol=self.var_tol,
            var_dtype=_VAR_DTYPES[self.var_dtype],
            dtype=self.dtype,
            device=self.device,
        )
        grp.extend(E, MU, VAR)
        self.groups[str(g)] = grp
        self._warn_if_amplified(g)

    def _group_add(self, g, E, MU, VAR) -> None:
        if self._group(g).extend(E, MU, VAR):
            # jitter on the new rows only would favour the old ones (a duplicate added with
            # variance 0 would be ignored): refit, so add and fit give the same map
            sel = self.labels == g
            self._group_fit(g, self.E[sel], self.MU[sel], self.VAR[sel])
        else:
            self._warn_if_amplified(g)

    def _group(self, g: int) -> _CholGroup:
        """Label ``g``'s group."""
        return cast(_CholGroup, self.groups[str(g)])

    def _warn_if_amplified(self, g: int) -> None:
        grp = self._group(g)
        warn_if_amplified(grp.coef[: grp.m], self.MU[self.labels == g], grp.mu0, f"label {g}")

    def _group_predict(self, g, Eq, *, need_var, approx_var):
        grp = self._group(g)
        mu = grp.mean(Eq)  # (Q, N)
        if not need_var:
            return mu, None
        return mu, (grp.var_approx(Eq) if approx_var else grp.var_exact(Eq))

    def _predict_subsets(self, Es, MUs, VARs, Eq, *, need_var):
        return local_gp(Es, MUs, VARs, Eq, self.alpha, need_var=need_var)
