"""Environment -> ProMP maps (Sec. III C, Eq. 7 and 8): one GP per weight, pluggable backends.

``make_env_map("torch" | "gpytorch" | "sparse", alpha, **options)`` builds one: the exact
closed form, GPyTorch's exact GPs, or local GPs over nearest neighbours for large data sets. All
share the :class:`EnvMap` contract (``fit``, ``add``, ``predict``, ``predict_mean``, ``save``) and
:func:`load_env_map` reads what ``save`` wrote.
"""

from __future__ import annotations

from pathlib import Path

from ..data.files import read_safetensors
from .base import ENV_MAP_FORMAT, ENV_MAP_SCHEMA, BestPrediction, EnvMap, EnvMapWarning, rbf
from .closed_form import TorchEnvMap
from .gpytorch_exact import GPyTorchEnvMap
from .sparse import SparseEnvMap

__all__ = [
    "EnvMap",
    "BestPrediction",
    "EnvMapWarning",
    "TorchEnvMap",
    "GPyTorchEnvMap",
    "SparseEnvMap",
    "BACKENDS",
    "make_env_map",
    "load_env_map",
    "rbf",
]

BACKENDS: dict[str, type[EnvMap]] = {
    "torch": TorchEnvMap,
    "gpytorch": GPyTorchEnvMap,
    "sparse": SparseEnvMap,
}


def make_env_map(backend: str = "torch", alpha: float = 1.0, **options) -> EnvMap:
    """An empty environment map of the given backend (``"torch"``, ``"gpytorch"``, ``"sparse"``).

    ``options``: ``nearest_k``, ``dtype``, ``device`` for every backend, plus the backend's own
    (see :class:`TorchEnvMap`, :class:`GPyTorchEnvMap`, :class:`SparseEnvMap`). Unknown names
    raise ``TypeError``; an unknown backend ``ValueError``.

    >>> env_map = make_env_map("torch", alpha=1.0, nearest_k=30)
    >>> env_map.fit(torch.rand(5, 2), torch.rand(5, 4), torch.full((5, 4), 0.1)).num_weights
    4
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown GP backend {backend!r}; choose one of {sorted(BACKENDS)}")
    return BACKENDS[backend](alpha, **options)


def load_env_map(path: str | Path, *, backend: str | None = None, **options) -> EnvMap:
    """Rebuild (refit) an environment map saved by :meth:`EnvMap.save`.

    ``backend`` and ``options`` override the saved ones (e.g. ``device="cuda"``).
    """

    tensors, meta = read_safetensors(
        path, fmt=ENV_MAP_FORMAT, schema_version=ENV_MAP_SCHEMA, keys=("E", "MU", "VAR", "labels")
    )
    saved = dict(meta.get("options", {}))
    if backend is not None and backend != meta["backend"]:  # the other backend's options differ
        saved = {"nearest_k": saved.get("nearest_k")}
    opts = {**saved, **options}
    env_map = make_env_map(backend or meta["backend"], meta["alpha"], **opts)
    if tensors["E"].shape[0]:
        env_map.fit(tensors["E"], tensors["MU"], tensors["VAR"], tensors["labels"])
    return env_map
