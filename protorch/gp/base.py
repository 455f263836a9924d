"""The environment map of PRO (Ewerton et al. 2019, Sec. III C): one GP per ProMP weight.

Known environments ``E (M, d)`` each carry a diagonal weight Gaussian ``MU (M, N)``,
``VAR (M, N)``. For weight ``n`` and a new environment ``e`` (Eq. 7, 8)::

    k(e_i, e_j) = exp(-alpha ||e_i - e_j||^2)
    A_n         = K + diag(VAR[:, n])                           (heteroscedastic noise)
    mu_n(e)     = mu0_n + k_e^T A_n^-1 (MU[:, n] - mu0_n)       mu0_n  = mean_m MU[m, n]
    var_n(e)    = k(e, e) + vbar_n - k_e^T A_n^-1 k_e           vbar_n = mean_m VAR[m, n]

:class:`EnvMap` holds the data, validates every input before touching its state, groups the data
by label (each label is a separate set of GPs: solutions passing left and right of an obstacle
are never averaged) and implements ``nearest_k`` (each query uses the GP of Eq. 7, 8 built on
its ``k`` nearest known environments of its label, prior mean and average variance included).
A backend implements the exact solve for one label group (``_group_*``) and for a batch of
per-query subsets (``_predict_subsets``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Callable, NamedTuple

import torch
from torch import Tensor, nn

from ..checks import check_nonnegative, check_positive, check_tensor
from ..data.files import atomic_write_safetensors
from .kernels import EnvMapWarning, posdef_cholesky, rbf, sq_dist
from .storage import GrowingRows

__all__ = [
    "EnvMap",
    "BestPrediction",
    "EnvMapWarning",
    "rbf",
    "sq_dist",
    "posdef_cholesky",
    "ENV_MAP_FORMAT",
    "ENV_MAP_SCHEMA",
]

ENV_MAP_FORMAT = "protorch.env_map"
ENV_MAP_SCHEMA = 2  # 2: metadata digests


def _as_labels(labels, m: int, device) -> Tensor:
    """``None`` / int / ``(m,)`` integer array -> ``(m,)`` int64 tensor."""
    if labels is None:
        return torch.zeros(m, dtype=torch.long, device=device)
    if isinstance(labels, (int,)) and not isinstance(labels, bool):
        return torch.full((m,), int(labels), dtype=torch.long, device=device)
    lab = torch.as_tensor(labels, device=device)
    if lab.ndim == 0:
        lab = lab.expand(m)
    if lab.ndim != 1 or lab.shape[0] != m:
        raise ValueError(
            f"labels must be an int or have shape ({m},), got shape {tuple(lab.shape)}"
        )
    if lab.is_floating_point():
        if not bool(torch.isfinite(lab).all()) or not bool((lab == lab.round()).all()):
            raise ValueError("labels must be integers")
    elif lab.dtype == torch.bool or lab.is_complex():
        raise ValueError(f"labels must be integers, got dtype {lab.dtype}")
    return lab.to(torch.long)


class BestPrediction(NamedTuple):
    """What :meth:`EnvMap.predict_best` returns for ``Q`` queries and ``K`` candidate labels."""

    mean: Tensor  # (Q, N) the chosen label's mean
    var: Tensor | None  # (Q, N) its variance (None with need_var=False)
    label: Tensor  # (Q,) long, the chosen label
    scores: Tensor  # (Q, K) every candidate's score (inf where the score was not finite)
    candidates: Tensor  # (K,) long, the labels tried, in the order of the scores' columns


class EnvMap(nn.Module, ABC):
    """Environment ``(Q, d)`` -> diagonal weight Gaussian ``(mu (Q, N), var (Q, N))``.

    Args:
        alpha: kernel parameter of ``exp(-alpha ||e_i - e_j||^2)``, > 0.
        nearest_k: if set, each query uses only its ``k`` nearest known environments (of its
            label), as the authors' code does with ``k = 30``; ties are broken by insertion
            order, so ``add`` in steps and a refit choose the same neighbours.
        dtype, device: of the stored data and the computations (float64 by default).

    Use :meth:`fit` to set the data, :meth:`add` to append without refitting, :meth:`predict`
    (or :meth:`predict_mean`) to query, :meth:`save` / :func:`protorch.gp.load_env_map` to
    persist. Every method validates its inputs completely before changing any state.
    """

    backend: str = "base"
    _known: Tensor  # (K,) the labels stored so far, sorted (a registered buffer)

    def __init__(
        self,
        alpha: float,
        *,
        nearest_k: int | None = None,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        check_positive(alpha, "alpha")
        if nearest_k is not None:
            if isinstance(nearest_k, bool) or int(nearest_k) != nearest_k or int(nearest_k) < 1:
                raise ValueError(f"nearest_k must be None or an int >= 1, got {nearest_k!r}")
            nearest_k = int(nearest_k)
        if not dtype.is_floating_point:
            raise ValueError(f"dtype must be a floating dtype, got {dtype}")
        self.alpha = float(alpha)
        self.nearest_k = nearest_k
        self._m = 0  # number of stored points
        self._first_new = 0  # the first row of the last fit or add
        self._d = self._n = 0  # env dim d, weights N
        # the data in blocks that are never copied, so one add never pays for the rows before it
        self._data = GrowingRows(
            (0,), dtype=dtype, device=device
        )  # (M, d + 2N) rows [E | MU | VAR]
        self._labels = GrowingRows((), dtype=torch.long, device=device)  # (M,)
        self.register_buffer(
            "_known", torch.zeros(0, dtype=torch.long, device=device)
        )  # (K,) sorted labels

    # ----------------------------------------------------------------- state
    @property
    def num_points(self) -> int:
        """``M``, the number of known environments."""
        return self._m

    @property
    def env_dim(self) -> int:
        return self._d

    @property
    def num_weights(self) -> int:
        return self._n

    def _columns(self, a: int, b: int) -> Tensor:
        """Columns ``a .. b - 1`` of the stored rows ``[E | MU | VAR]``: ``(M, b - a)``, a copy."""
        return (
            torch.cat([v[:, a:b] for _, v in self._data.segments(0, self._m)])
            if self._m
            else self._data.b0[:0, a:b]
        )

    @property
    def E(self) -> Tensor:
        return self._columns(0, self.env_dim)  # (M, d) a copy

    @property
    def MU(self) -> Tensor:
        return self._columns(self._d, self._d + self._n)  # (M, N) a copy

    @property
    def VAR(self) -> Tensor:
        return self._columns(self._d + self._n, self._d + 2 * self._n)  # (M, N) a copy

    @property
    def labels(self) -> Tensor:
        return self._labels.rows(0, self._m)  # (M,)

    def _take(self, rows: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Storage ``rows (...)`` -> their ``E (..., d), MU (..., N), VAR (..., N)``, contiguous."""
        d, n = self._d, self._n
        x = self._data.take(rows)  # (..., d + 2N)
        return x[..., :d].contiguous(), x[..., d : d + n].contiguous(), x[..., d + n :].contiguous()

    @property
    def dtype(self) -> torch.dtype:
        return self._data.dtype

    @property
    def device(self) -> torch.device:
        return self._data.device

    def options(self) -> dict:
        """Constructor options (JSON-serialisable) that :meth:`save` records."""
        return {"nearest_k": self.nearest_k}

    def extra_repr(self) -> str:
        return (
            f"backend={self.backend!r}, alpha={self.alpha:g}, nearest_k={self.nearest_k}, "
            f"M={self._m}"
        )

    # ------------------------------------------------------------ validation
    def _validate(self, E, MU, VAR, labels, *, appending: bool):
        E = check_tensor(E, "E", ndim=2)
        MU = check_tensor(MU, "MU", ndim=2)
        VAR = check_tensor(VAR, "VAR", ndim=2)
        for x, name in ((E, "E"), (MU, "MU"), (VAR, "VAR")):
            if not x.is_floating_point():
                raise ValueError(f"{name} must be a floating-point tensor, got {x.dtype}")
        m = E.shape[0]
        if m == 0:
            raise ValueError("E is empty: give at least one environment")
        if MU.shape[0] != m or VAR.shape[0] != m:
            raise ValueError(
                f"E, MU and VAR must have the same number of rows, got {m}, {MU.shape[0]}, "
                f"{VAR.shape[0]}"
            )
        if MU.shape != VAR.shape:
            raise ValueError(
                f"MU and VAR must have the same shape, got {tuple(MU.shape)} and {tuple(VAR.shape)}"
            )
        if E.shape[1] == 0 or MU.shape[1] == 0:
            raise ValueError(
                f"E and MU need at least one column, got {tuple(E.shape)} and {tuple(MU.shape)}"
            )
        check_nonnegative(VAR, "VAR")
        if appending and self._m > 0:
            if E.shape[1] != self.env_dim:
                raise ValueError(
                    f"E must have {self.env_dim} columns like the stored data, got {E.shape[1]}"
                )
            if MU.shape[1] != self.num_weights:
                raise ValueError(
                    f"MU must have {self.num_weights} columns like the stored data, got "
                    f"{MU.shape[1]}"
                )
        kw = dict(dtype=self.dtype, device=self.device)
        lab = _as_labels(labels, m, self.device)
        return E.to(**kw), MU.to(**kw), VAR.to(**kw), lab

    def _validate_query(self, E, labels) -> tuple[Tensor, Tensor]:
        if self._m == 0:
            raise RuntimeError("the environment map has no data: call fit() first")
        E = check_tensor(E, "E", ndim=2)
        if not E.is_floating_point():
            raise ValueError(f"E must be a floating-point tensor, got {E.dtype}")
        if E.shape[1] != self.env_dim:
            raise ValueError(f"E must be (Q, {self.env_dim}), got {tuple(E.shape)}")
        known = self._known
        if labels is None:
            if known.numel() > 1:
                raise ValueError(
                    f"the data has several labels {known.tolist()}: pass labels= to predict per "
                    "label"
                )
            lab = known.expand(E.shape[0])
        else:
            lab = _as_labels(labels, E.shape[0], self.device)
            missing = sorted(set(torch.unique(lab).tolist()) - set(known.tolist()))
            if missing:
                raise ValueError(
                    f"no known environment has label(s) {missing}; known: {known.tolist()}"
                )
        return E.to(dtype=self.dtype, device=self.device), lab

    # ------------------------------------------------------------------ API
    def fit(self, E: Tensor, MU: Tensor, VAR: Tensor, labels=None) -> "EnvMap":
        """Replace the data: ``E (M, d)``, ``MU (M, N)``, ``VAR (M, N) >= 0``, ``labels (M,)``."""
        E, MU, VAR, lab = self._validate(E, MU, VAR, labels, appending=False)
        before = (
            None if self._m == 0 else (self.E, self.MU, self.VAR, self.labels.clone())
        )  # copies
        try:
            self._m = 0
            self._reset_groups()
            self._append_storage(E, MU, VAR, lab)
            if self._keeps_groups():
                for g in torch.unique(lab).tolist():
                    sel = lab == g
                    self._group_fit(g, E[sel], MU[sel], VAR[sel])
        except BaseException:
            self._restore(before)
            raise
        return self

    def add(self, E: Tensor, MU: Tensor, VAR: Tensor, labels=None) -> "EnvMap":
        """Append ``B`` environments without refitting the existing ones (same shapes as fit)."""
        if self._m == 0:
            return self.fit(E, MU, VAR, labels)
        E, MU, VAR, lab = self._validate(E, MU, VAR, labels, appending=True)
        m = self._m
        try:
            self._append_storage(E, MU, VAR, lab)
            if self._keeps_groups():
                for g in torch.unique(lab).tolist():
                    sel = lab == g
                    if self._has_group(g):
                        self._group_add(g, E[sel], MU[sel], VAR[sel])
                    else:
                        self._group_fit(g, E[sel], MU[sel], VAR[sel])
        except BaseException:  # e.g. a factorisation that failed half-way: back to the m points
            self._m = m  # the first m rows are untouched
            self._restore((self.E, self.MU, self.VAR, self.labels.clone()))
            raise
        return self

    def _restore(self, data: tuple[Tensor, Tensor, Tensor, Tensor] | None) -> None:
        """Back to the map of ``data`` (``None``: empty) after a fit or add that failed part-way;
        refits, which is paid only on that rare path."""
        self._m = 0
        self._reset_groups()
        if data is not None:
            self.fit(*data)

    def predict(self, E: Tensor, labels=None, *, approx_var: bool = False) -> tuple[Tensor, Tensor]:
        """``E (Q, d)`` -> ``(mu (Q, N), var (Q, N))`` by Eq. 7 and 8, per label.

        ``approx_var=True`` uses the backend's fast approximate variance (see its docs); the
        mean is exact either way.
        """
        return self._predict(E, labels, need_var=True, approx_var=approx_var)

    def predict_mean(self, E: Tensor, labels=None) -> Tensor:
        """``E (Q, d)`` -> ``mu (Q, N)`` (Eq. 7) only; the fast path for online queries."""
        return self._predict(E, labels, need_var=False, approx_var=False)[0]

    def forward(self, E: Tensor, labels=None) -> tuple[Tensor, Tensor]:
        return self.predict(E, labels)

    def predict_best(
        self,
        E: Tensor,
        score: Callable[[Tensor, Tensor], Tensor],
        *,
        candidates=None,
        need_var: bool = True,
        approx_var: bool = False,
    ) -> BestPrediction:
        """Predict every candidate label's Gaussian at each query and keep, per query, the label
        whose mean scores lowest: the label-aware inference for multimodal data (each label a
        homotopy class, say; their means are compared, never averaged).

        Args:
            E: ``(Q, d)`` queries.
            score: ``(mu (K Q, N), E (K Q, d)) -> (K Q,)``, lower is better (e.g. the task's
                summed objectives of the mean trajectory); called once, on all ``K`` labels'
                means stacked label-major. A non-finite score counts as ``inf``.
            candidates: the labels to try (default: every label in the data).
        """
        if candidates is None:
            if self._m == 0:
                raise RuntimeError("the environment map has no data: call fit() first")
            cand = self._known  # (K,)
        else:
            cand = torch.as_tensor(candidates, device=self.device).reshape(-1)
            cand = torch.unique(_as_labels(cand, cand.numel(), self.device))  # (K,)
            if cand.numel() == 0:
                raise ValueError("candidates is empty: give at least one label")
        E = check_tensor(E, "E", ndim=2)
        q, k = E.shape[0], cand.numel()
        e_rep = E.repeat(k, 1)  # (K Q, d) label-major
        mu, var = self._predict(
            e_rep, cand.repeat_interleave(q), need_var=need_var, approx_var=approx_var
        )
        s = torch.as_tensor(score(mu, e_rep))
        if tuple(s.shape) != (k * q,):
            raise ValueError(
                f"score must return ({k * q},) values for {k} labels x {q} queries, got "
                f"{tuple(s.shape)}"
            )
        s = (
            torch.where(torch.isfinite(s), s, torch.full_like(s, float("inf"))).reshape(k, q).T
        )  # (Q, K)
        best = s.argmin(-1).to(self.device)  # (Q,)
        rows = best * q + torch.arange(q, device=self.device)  # (Q,)
        return BestPrediction(mu[rows], None if var is None else var[rows], cand[best], s, cand)

    def _predict(self, E, labels, *, need_var: bool, approx_var: bool):
        E, lab = self._validate_query(E, labels)
        q, n = E.shape[0], self.num_weights
        mu = torch.empty(q, n, dtype=self.dtype, device=self.device)  # (Q, N)
        var: Tensor | None = (
            torch.empty(q, n, dtype=self.dtype, device=self.device) if need_var else None
        )  # (Q, N)
        for g in torch.unique(lab).tolist():
            sel = lab == g
            if self._keeps_groups():
                m_g, v_g = self._group_predict(g, E[sel], need_var=need_var, approx_var=approx_var)
            else:
                m_g, v_g = self._nearest_predict(g, E[sel], need_var=need_var)
            mu[sel] = m_g
            if var is not None:
                var[sel] = v_g
        return mu, var

    def _nearest_predict(self, g: int, Eq: Tensor, *, need_var: bool):
        rows = (self.labels == g).nonzero()[:, 0]  # (Mg,) storage rows of label g
        if self.nearest_k is None:
            raise RuntimeError("_nearest_predict needs nearest_k set")
        k = min(self.nearest_k, rows.shape[0])
        d2 = sq_dist(Eq, self.E[rows])  # (Q, Mg)
        idx = torch.sort(d2, dim=1, stable=True).indices[:, :k]  # (Q, k), ties by insertion order
        return self._predict_subsets(*self._take(rows[idx]), Eq, need_var=need_var)

    # -------------------------------------------------------------- storage
    def _append_storage(self, E: Tensor, MU: Tensor, VAR: Tensor, lab: Tensor) -> None:
        m = self._m
        if m == 0:  # fresh blocks: the old ones may still back the caller's tensors
            self._d, self._n = E.shape[1], MU.shape[1]
            self._data = GrowingRows((self._d + 2 * self._n,), dtype=self.dtype, device=self.device)
            self._labels = GrowingRows((), dtype=torch.long, device=self.device)
        self._data.append(E, MU, VAR)  # (B, d + 2N) rows
        self._labels.append(lab)
        known = self._known if m else self._known[:0]  # (K,) the labels stored so far
        self._known = torch.unique(torch.cat([known, lab]))  # (K',) sorted
        self._first_new, self._m = m, m + E.shape[0]

    def _new_rows(self, g: int) -> Tensor:
        """Storage rows ``(B_g,)`` of label ``g`` among those the running fit or add appended."""
        return self._first_new + (self._labels.rows(self._first_new, self._m) == g).nonzero()[:, 0]

    # --------------------------------------------------------- persistence
    def save(self, path: str | Path) -> Path:
        """Write the data and settings to one safetensors file, atomically."""

        tensors = {"E": self.E, "MU": self.MU, "VAR": self.VAR, "labels": self.labels}
        meta = {
            "format": ENV_MAP_FORMAT,
            "schema_version": ENV_MAP_SCHEMA,
            "backend": self.backend,
            "alpha": self.alpha,
            "options": self.options(),
        }
        return atomic_write_safetensors(path, tensors, meta)

    # -------------------------------------------------------- backend hooks
    def _keeps_groups(self) -> bool:
        """Whether ``fit`` and ``add`` build per-label state (``_group_*``) and queries use it;
        otherwise (``nearest_k`` set) every query solves on its neighbours
        (``_predict_subsets``)."""
        return self.nearest_k is None

    @abstractmethod
    def _reset_groups(self) -> None:
        """Forget every fitted group."""

    @abstractmethod
    def _has_group(self, g: int) -> bool: ...

    @abstractmethod
    def _group_fit(self, g: int, E: Tensor, MU: Tensor, VAR: Tensor) -> None:
        """Exact GPs of label ``g`` from its data ``(Mg, d), (Mg, N), (Mg, N)``."""

    @abstractmethod
    def _group_add(self, g: int, E: Tensor, MU: Tensor, VAR: Tensor) -> None:
        """Append ``(B, d), (B, N), (B, N)`` to label ``g`` (prior mean and vbar change too)."""

    @abstractmethod
    def _group_predict(self, g: int, Eq: Tensor, *, need_var: bool, approx_var: bool):
        """``Eq (Q, d)`` -> ``(mu (Q, N), var (Q, N) or None)`` for label ``g``."""

    @abstractmethod
    def _predict_subsets(
        self, Es: Tensor, MUs: Tensor, VARs: Tensor, Eq: Tensor, *, need_var: bool
    ):
        """Query ``q`` uses only its own data ``Es[q] (k, d), MUs[q] (k, N), VARs[q] (k, N)``:
        ``(Q, k, d), (Q, k, N), (Q, k, N), (Q, d)`` -> ``(mu (Q, N), var (Q, N) or None)``."""
