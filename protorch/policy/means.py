"""The per-call pieces of :class:`~protorch.policy.policy.Policy`: every class's mean weights at
one environment (:class:`ClassMeans`, the map's Eq. 7 on each class's nearest neighbours, their
solves cached and updated when one neighbour is swapped for another) and the ProMP basis with its
phase derivatives (:func:`basis3`)."""

from __future__ import annotations

import math
from collections import OrderedDict

import torch
from torch import Tensor

from ..gp.kernels import posdef_cholesky, rbf, sq_dist

__all__ = ["ClassMeans", "EndEffector", "basis3", "decay_matrix"]

MAX_UPDATES = 64  # swaps applied to one factorised set before the next new set is factorised afresh
SPARE = 60  # known environments beyond the k nearest kept as the candidates of the next searches
# a new set differing from its source by more environments is factorised afresh (three swaps cost
# more)
MAX_SWAPS = 2
MAX_RANK = (
    8  # rank of the pending terms a swap adds to (two per swap) before it writes the inverse itself
)
MARGIN = (
    1e-9  # metres (environment units) of slack in the test that the neighbours cannot have changed
)


class _Set:
    """One class's neighbour set and its solve, in slot order (a swap replaces one slot):
    ``rows (k,)`` into the class's data, ``Es (k, d)``, ``coef = A^-1 (MU_S - mu0) (k, N)``,
    ``mu0 (N,)``; for updates the inverse ``A^-1 = inv + U V`` with ``inv (N, k, k)`` (``None``:
    made from ``chol`` when first needed; shared with the set it was updated from) and the pending
    rank-``r`` terms ``U (N, k, r)``, ``V (N, r, k)`` (``None``: none), ``K (k, k)`` the kernel
    matrix, ``depth`` the swaps since the last factorisation."""

    __slots__ = ("rows", "Es", "coef", "mu0", "inv", "U", "V", "chol", "K", "MUs", "VARs", "depth")

    def __init__(
        self,
        rows,
        Es,
        coef,
        mu0,
        inv=None,
        chol=None,
        K=None,
        MUs=None,
        VARs=None,
        depth=0,
        U=None,
        V=None,
    ) -> None:
        self.rows, self.Es, self.coef, self.mu0 = rows, Es, coef, mu0
        self.inv, self.U, self.V, self.chol, self.K, self.depth = inv, U, V, chol, K, depth
        self.MUs, self.VARs = MUs, VARs  # (k, N) the set's data, in slot order

    @property
    def factored(self) -> bool:
        """Whether the set holds its inverse or its factor (a swap can start from it)."""
        return self.inv is not None or self.chol is not None

    def times(self, x: Tensor) -> Tensor:
        """``A^-1 x`` for every weight: ``x (k,)`` (one vector for all) or ``(N, k)`` (one per
        weight) -> ``(N, k)``; one pass over ``inv``, the pending terms by two small products."""
        if x.dim() == 1:
            out = torch.matmul(
                self.inv, x
            )  # (N, k) one matrix-vector product over all weights' rows
            return (
                out
                if self.U is None
                else out + torch.bmm(self.U, torch.matmul(self.V, x)[..., None])[..., 0]
            )
        out = torch.linalg.vecdot(
            self.inv, x[:, None, :]
        )  # (N, k) A^-1 is symmetric: row-wise dot products
        return (
            out
            if self.U is None
            else out + torch.bmm(self.U, torch.bmm(self.V, x[..., None]))[..., 0]
        )

    def write(self) -> None:
        """Write the pending terms into a new inverse (one pass over it; sets sharing the old
        ``inv`` keep theirs)."""
        self.inv, self.U, self.V = torch.baddbmm(self.inv, self.U, self.V), None, None

    def column(self, j: int) -> Tensor:
        """Column ``j`` of every weight's ``A^-1``: ``(N, k)``."""
        col = self.inv[:, :, j]
        return col if self.U is None else col + torch.bmm(self.U, self.V[:, :, j : j + 1])[..., 0]


class ClassMeans:
    """Every class's mean weights at one environment, ``env (d,) -> (K, N)`` float64.
    ``labels (K,)`` names the classes in the rows' order.

    With ``nearest_k`` (the map answers each query from the class's ``k`` nearest known
    environments) each class keeps its current neighbour set: a call first checks, by the triangle
    inequality on the distances found at the last full search, whether the set can have changed
    (it cannot while the environment moved by less than half the gap between the ``k``-th and the
    ``k+1``-th distance); otherwise one distance pass and a ``topk`` find the set, as the map does
    (ties by insertion order), over the ``k + SPARE`` nearest of the last full pass while they
    certainly hold the set (:meth:`_search`). The solve ``A^-1 (MU_S - mu0)`` of a set is cached
    (``cache_size`` sets); a new set that differs by one environment (or up to
    :data:`MAX_SWAPS`, one after the other) from the class's :attr:`base`, its newest set holding
    an inverse (a set taken back from the cache holds none once :data:`factor_cache` newer ones
    were made), is solved by a rank-2 update of that inverse (``A^-1`` with one row and column
    replaced: one rank-1 downdate, one rank-1 update, per weight) and one step of iterative
    refinement against ``A`` itself, otherwise (or after :data:`MAX_UPDATES` chained swaps)
    factorised afresh with the map's own :func:`~protorch.gp.kernels.posdef_cholesky`, float64
    throughout. The updates are kept as low-rank terms beside the inverse they started from
    (:class:`_Set`): a swap reads the ``(N, k, k)`` inverses (half a MB for 70 weights and 30
    neighbours, read from beyond the core's cache) three times and writes none; a call with time to
    spare writes them (:meth:`prepare`), or a swap once they reach rank :data:`MAX_RANK`."""

    def __init__(self, env_map, *, cache_size: int = 2048, factor_cache: int = 8) -> None:
        self.map = env_map
        self.labels = torch.unique(env_map.labels)  # (K,)
        self.alpha = env_map.alpha
        self.cache_size, self.factor_cache = int(cache_size), int(factor_cache)
        self.misses = 0  # new neighbour sets solved (factorised or updated)
        self.updates = 0  # of which by a swap update
        self.full_searches = 0  # distance passes over all of a class's environments
        kw = dict(dtype=torch.float64, device=env_map.device)
        E, MU, VAR, lab = (
            env_map.E.to(**kw),
            env_map.MU.to(**kw),
            env_map.VAR.to(**kw),
            env_map.labels,
        )
        k_near = env_map.nearest_k
        groups = getattr(env_map, "groups", None)
        self.mode = "generic"
        if k_near is not None:
            self.mode = "nearest"
            self.rows = [
                torch.nonzero(lab == g).flatten() for g in self.labels.tolist()
            ]  # per class
            self.E = [E[r].contiguous() for r in self.rows]  # (Mg, d) per class
            self.MU = [MU[r].contiguous() for r in self.rows]  # (Mg, N)
            self.VAR = [VAR[r].contiguous() for r in self.rows]  # (Mg, N)
            self.k = [min(k_near, r.numel()) for r in self.rows]
            self.cache: OrderedDict = OrderedDict()  # (class, sorted rows) -> _Set
            self.factored: OrderedDict = (
                OrderedDict()
            )  # the sets holding a factor (id -> _Set), newest last
            self.base: list[_Set | None] = [None] * len(
                self.rows
            )  # per class, its newest set holding a factor
            self.reset()
        elif getattr(env_map, "backend", "") == "torch" and groups is not None:
            self.mode = "exact"
            grp = [groups[str(g)] for g in self.labels.tolist()]
            sizes = [g.m for g in grp]
            self.E_all = torch.cat([g.E[: g.m] for g in grp]).to(**kw)  # (M, d)
            self.coef = torch.cat([g.coef[: g.m] for g in grp]).to(
                **kw
            )  # (M, N) A^-1 (MU - mu0), the map's own
            self.mu0 = torch.stack([g.mu0 for g in grp]).to(**kw)  # (K, N)
            self.mask = torch.zeros(
                len(grp), sum(sizes), **kw
            )  # (K, M) block diagonal: each class its rows
            start = 0
            for c, m in enumerate(sizes):
                self.mask[c, start : start + m] = 1.0
                start += m

    def reset(self) -> None:
        """Forget each class's current set (the cache of solves and each class's :attr:`base`, the
        set the next swap updates, stay)."""
        if self.mode == "nearest":
            n = len(self.E)
            self.current: list[_Set | None] = [None] * n
            self.anchor: list[tuple[list[float], float] | None] = [
                None
            ] * n  # (env, half the gap) of the last search
            self.cands: list[tuple | None] = [
                None
            ] * n  # (env, half the gap, rows (C,), E[rows] (C, d)) of the last full search

    # ----------------------------------------------------------------- nearest neighbours
    def _search(self, c: int, env: Tensor, point: list[float]) -> tuple:
        """The sorted rows (of class ``c``) of the ``k`` nearest known environments, as the map
        picks them (ties by insertion order), as a tuple; remembers the gap for :meth:`_unchanged`.
        A full search keeps the ``k + SPARE`` nearest as candidates: while the environment stays
        within half the gap between the ``k``-th and the first non-candidate's distance of that
        search, the ``k`` nearest are among them and only they are searched."""
        E, k = self.E[c], self.k[c]
        if k == E.shape[0]:
            self.anchor[c] = (point, math.inf)
            return tuple(range(k))
        cand = self.cands[c]
        if cand is not None and math.dist(point, cand[0]) < cand[1]:
            rows, Ec = cand[2], cand[3]  # (C,) sorted rows, (C, d)
            d2 = sq_dist(env[None], Ec)[0]  # (C,) as the map computes them
        else:
            rows, d2 = None, sq_dist(env[None], E)[0]  # (Mg,)
            self.full_searches += 1
        n = min(k + SPARE + 1, d2.shape[0]) if rows is None else k + 1
        vals, idx = torch.topk(d2, n, largest=False, sorted=True)  # (n,)
        v = vals.tolist()
        if rows is None:
            if (
                n > k + SPARE
            ):  # the candidates (sorted rows, so that a stable sort keeps the map's tie order)
                keep = torch.sort(idx[: k + SPARE]).values
                self.cands[c] = (
                    point,
                    0.5 * (math.sqrt(v[-1]) - math.sqrt(v[k - 1])) - MARGIN,
                    keep,
                    E[keep],
                )
            else:
                self.cands[c] = None
        if v[k] > v[k - 1]:
            self.anchor[c] = (point, 0.5 * (math.sqrt(v[k]) - math.sqrt(v[k - 1])) - MARGIN)
        else:  # a tie at the k-th distance: the map's stable order decides
            idx = torch.sort(d2, stable=True).indices
            self.anchor[c] = None
        idx = idx[:k] if rows is None else rows[idx[:k]]
        return tuple(sorted(idx.tolist()))

    def _unchanged(self, c: int, point: list[float]) -> bool:
        """Whether class ``c``'s set is certainly the one of the last search: no known environment
        can have crossed the ``k``-th distance since (each distance moved by at most the
        environment's displacement)."""
        a = self.anchor[c]
        if a is None or self.current[c] is None:
            return False
        return math.dist(point, a[0]) < a[1]

    def _factorise(self, c: int, rows: tuple) -> _Set:
        """The solve of a new set (the same solve as :func:`~protorch.gp.kernels.local_gp`)."""
        r = torch.tensor(rows, device=self.E[c].device)
        Es, MUs, VARs = self.E[c][r], self.MU[c][r], self.VAR[c][r]  # (k, d), (k, N), (k, N)
        n = MUs.shape[1]
        K = rbf(Es, Es, self.alpha)  # (k, k)
        A = K[None].repeat(n, 1, 1)  # (N, k, k)
        A.diagonal(dim1=-2, dim2=-1).add_(VARs.T)  # K + diag(VAR[:, n]) per weight
        L, jitter = posdef_cholesky(A)  # (N, k, k)
        mu0 = MUs.mean(0)  # (N,)
        coef = torch.cholesky_solve((MUs - mu0).T[..., None], L)[..., 0].T.contiguous()  # (k, N)
        exact = not bool(jitter.any())  # a jittered factor is not A's: no updates from it
        return _Set(list(rows), Es, coef, mu0, chol=L if exact else None, K=K, MUs=MUs, VARs=VARs)

    def _swap(self, c: int, old: _Set, out: int, new: int, solve: bool = True) -> _Set | None:
        """``old`` with the environment ``out`` replaced by ``new`` (rows of class ``c``): the
        inverse by a rank-1 downdate and a rank-1 update per weight, kept as two more pending
        terms (:class:`_Set`: ``old.inv`` is only read; :meth:`prepare` or a swap past
        :data:`MAX_RANK` writes them into a new inverse), the coefficients (``solve``) by one
        product and one step of iterative refinement; ``None`` if the update is unusable."""
        self._invert(old)
        j = old.rows.index(out)
        e = self.E[c][new]  # (d,)
        b = rbf(e[None], old.Es, self.alpha)[0]  # (k,) the new environment's kernel with the set
        b[j] = 0.0
        gj = old.column(j)  # (N, k)
        u = gj / gj[:, j : j + 1]  # (N, k)
        g = old.times(b)  # (N, k)
        g -= u * g[:, j : j + 1]  # (A^-1 - u gj^T) b: the set without slot j, times b
        s = 1.0 + self.VAR[c][new] - g @ b  # (N,) the Schur complement (k(e, e) = 1)
        if not bool((s > 0).all()):
            return None
        g[:, j] -= 1.0  # h = g - e_j
        # slot j removed (- u gj^T) and the new environment added in it (+ g g^T / s): two rank-1
        # terms
        U, V = (
            torch.stack([u, g / s[:, None]], -1),
            torch.stack([-gj, g], 1),
        )  # (N, k, 2), (N, 2, k)
        if old.U is not None:
            U, V = (
                torch.cat([old.U, U], -1),
                torch.cat([old.V, V], 1),
            )  # (N, k, r + 2), (N, r + 2, k)
        rows = list(old.rows)
        rows[j] = new
        Es = old.Es.clone()
        Es[j] = e
        b[j] = 1.0
        K = old.K.clone()
        K[j], K[:, j] = b, b
        MUs, VARs = old.MUs.clone(), old.VARs.clone()  # (k, N)
        MUs[j], VARs[j] = self.MU[c][new], self.VAR[c][new]
        out_set = _Set(
            rows,
            Es,
            None,
            None,
            inv=old.inv,
            K=K,
            MUs=MUs,
            VARs=VARs,
            depth=old.depth + 1,
            U=U,
            V=V,
        )
        if U.shape[-1] > MAX_RANK:  # one pass over the (N, k, k) inverses writes them all
            out_set.write()
        if not solve:
            return out_set
        out_set.mu0 = mu0 = MUs.mean(0)  # (N,)
        y = MUs - mu0  # (k, N)
        coef = out_set.times(y.T.contiguous()).T  # (k, N)
        resid = torch.addmm(y - VARs * coef, K, coef, alpha=-1.0)  # (k, N) y - A coef
        coef = coef + out_set.times(resid.T.contiguous()).T  # one step of iterative refinement
        out_set.coef = coef.contiguous()
        return out_set

    @staticmethod
    def _invert(s: _Set) -> None:
        """``s``'s inverses ``(N, k, k)`` from its Cholesky factor (what a swap update starts
        from)."""
        if (
            s.inv is None
        ):  # LAPACK's inverse is column-major; A^-1 is symmetric (exactly, on the CPU), so its
            s.inv = torch.cholesky_inverse(
                s.chol
            ).mT  # transpose is it in row-major order: products 5x faster
            s.chol = None

    def prepare(self, c: int) -> bool:
        """Make class ``c``'s set ready for the next swap update: its inverses from a fresh factor
        (about a third of a swap call, otherwise paid by the call that swaps), or its pending
        terms written into them once they are past half of :data:`MAX_RANK` (the next swaps then
        start from rank 0); for a call with time to spare. The same means to round-off as when
        the swaps do it. Whether there was work."""
        s = self.base[c] if self.mode == "nearest" else None
        if s is None:
            return False
        if s.inv is None and s.chol is not None:
            self._invert(s)
            return True
        if (
            s.U is not None and 2 * s.U.shape[-1] > MAX_RANK
        ):  # (written from rank MAX_RANK / 2 + 2 on)
            s.write()
            return True
        return False

    def _keep_factor(self, s: _Set) -> None:
        """Hold ``s``'s factor among the :attr:`factor_cache` newest (the others' are dropped,
        never a class's :attr:`base`)."""
        self.factored[id(s)] = s
        self.factored.move_to_end(id(s))
        keep = {id(x) for x in self.base if x is not None}
        for key in list(self.factored):
            if len(self.factored) <= self.factor_cache + len(keep):
                break
            if key not in keep:
                old = self.factored.pop(key)
                old.inv = old.U = old.V = old.chol = old.K = old.MUs = old.VARs = None

    def neighbour_set(self, c: int, env: Tensor, point: list[float] | None = None) -> _Set:
        """Class ``c``'s neighbour set at ``env (d,)`` and its solve (class docstring)."""
        point = env.tolist() if point is None else point
        if self._unchanged(c, point):
            return self.current[c]
        rows = self._search(c, env, point)
        cur = self.current[c]
        if cur is not None and sorted(cur.rows) == list(rows):
            return cur
        key = (c, rows)
        hit = self.cache.get(key)
        if hit is not None:
            self.cache.move_to_end(key)
        else:
            self.misses += 1
            src = self.base[c]  # the class's newest set holding its inverse or factor
            if src is not None and src.depth < MAX_UPDATES and src.factored:
                gone, came = (
                    sorted(set(src.rows).difference(rows)),
                    sorted(set(rows).difference(src.rows)),
                )
                if len(gone) <= MAX_SWAPS:
                    hit = src
                    for i, (out, new) in enumerate(zip(gone, came)):  # one swap after the other
                        hit = (
                            None
                            if hit is None
                            else self._swap(c, hit, out, new, solve=i == len(gone) - 1)
                        )
                    self.updates += hit is not None
            if hit is None:
                hit = self._factorise(c, rows)
            self.cache[key] = hit
            if len(self.cache) > self.cache_size:
                self.cache.popitem(last=False)
        if hit.factored:
            self.base[c] = hit
            self._keep_factor(hit)
        self.current[c] = hit
        return hit

    def mean(self, c: int, env: Tensor, point: list[float] | None = None) -> Tensor:
        """Class row ``c``'s mean weights at ``env (d,)``: ``(1, N)``."""
        if self.mode != "nearest":
            return self(env, [c])
        s = self.neighbour_set(c, env, point)
        return torch.addmm(s.mu0[None], rbf(env[None], s.Es, self.alpha), s.coef)  # (1, N)

    def __call__(self, env: Tensor, classes: list[int] | None = None) -> Tensor:
        """``env (d,)`` float64 -> means ``(K', N)`` of ``classes`` (row indices into
        :attr:`labels`; all by default)."""
        cls = range(self.labels.numel()) if classes is None else classes
        if self.mode == "nearest":
            point = env.tolist()
            parts = [self.mean(c, env, point) for c in cls]
            return parts[0] if len(parts) == 1 else torch.cat(parts)  # (K', N)
        if self.mode == "exact":
            kq = rbf(env[None], self.E_all, self.alpha)  # (1, M)
            mask = self.mask if classes is None else self.mask[list(cls)]  # (K', M)
            mu0 = self.mu0 if classes is None else self.mu0[list(cls)]
            return mu0 + (mask * kq) @ self.coef  # (K', N) every class in one product
        lab = self.labels[list(cls)]  # (K',)
        return self.map.predict_mean(env.expand(lab.numel(), -1), lab).to(torch.float64)


def basis3(promp, z) -> Tensor:
    """The normalised Gaussian basis and its first two phase derivatives at the phases ``z``
    (a float, a 0-d or a ``(P,)`` tensor) of a float64 ``promp``: ``(..., 3, K)``,
    :meth:`~protorch.primitives.promp.ProMP.basis_at` ``(z, order=2)`` shaped as ``z``."""
    return promp.basis_at(z, order=2).reshape(*torch.as_tensor(z).shape, 3, -1)  # (..., 3, K)


def decay_matrix(blend: float, s: float, rows: int = 3, device=None) -> Tensor:
    """The critically damped decay at rate ``blend`` (1/s) of
    :class:`~protorch.policy.policy.Policy`'s
    continuity offset as a matrix ``(rows, 2)``: ``(d0, v0)`` -> position, velocity (and
    acceleration) ``s`` seconds later, ``d(s) = (d0 + (v0 + w d0) s) exp(-w s)``."""
    w, e = blend, math.exp(-blend * s)
    m = [
        [(1 + w * s) * e, s * e],
        [-w * w * s * e, (1 - w * s) * e],
        [(-w * w + w**3 * s) * e, (-2 * w + w * w * s) * e],
    ]
    return torch.tensor(m[:rows], dtype=torch.float64, device=device)


class EndEffector:
    """The end effector's position for a few joint configurations in a couple of dozen tensor
    operations: ``(P, J) -> (P, 3)``, the chain of
    :class:`~protorch.robots.kinematics.ArmKinematics`
    folded as it folds it (``G_0 Rz(q_1) G_1 ... Rz(q_J) G_J``), each joint's ``G Rz(q)`` built
    for every configuration at once and the end point carried back through them by one batched
    product per joint. The same numbers as ``ee_position`` to round-off; faster for the ~40
    configurations of a class decision, where ``ee_position``'s elementwise path (~90 operations
    of a few elements) is all per-operation overhead."""

    def __init__(self, kinematics, dtype=torch.float64, device=None) -> None:
        maps = torch.tensor(kinematics._maps, dtype=dtype, device=device)  # (J + 1, 3, 4)
        self.cols = maps[:-1, :, :3]  # (J, 3, 3) each joint's fixed map, linear part
        self.shift = maps[:-1, :, 3:]  # (J, 3, 1)
        self.tail = maps[-1, :, 3]  # (3,) the end point in the last joint's frame
        self.joints = self.cols.shape[0]

    def __call__(self, q: Tensor) -> Tensor:
        c, s = torch.cos(q.T)[..., None], torch.sin(q.T)[..., None]  # (J, P, 1)
        a0, a1 = self.cols[:, None, :, 0], self.cols[:, None, :, 1]  # (J, 1, 3)
        m = torch.stack(
            [
                torch.addcmul(a0 * c, a1, s),
                torch.addcmul(a1 * c, a0, s, value=-1.0),
                self.cols[:, None, :, 2].expand_as(a0 * c),
            ],
            -1,
        )  # (J, P, 3, 3) G_j[:3, :3] Rz(q_j)
        v = (m[-1] @ self.tail)[..., None] + self.shift[-1]  # (P, 3, 1)
        for j in range(self.joints - 2, -1, -1):
            v = torch.baddbmm(self.shift[j], m[j], v)  # (P, 3, 1)
        return v[..., 0]
