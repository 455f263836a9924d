"""The data set of the self-improvement loop: one entry per known environment.

An entry is ``(env (d,), mean (N,), var (N,), label, origin, converged, cost)``: the diagonal
ProMP weight Gaussian found for an environment, the label of its class (e.g. passing left or
right of an obstacle), where it came from (``"demonstration"``, ``"prior"`` or ``"learned"``),
whether the PRO run that produced it converged, and its final cost (NaN when unknown).

Saved as one safetensors file with JSON metadata (schema version, ProMP settings, task name; see
:mod:`protorch.data.checkpoint` for the layout); writes are atomic, loads never unpickle and refuse
truncated,
corrupted, foreign-schema and other-ProMP-size files with a
:class:`~protorch.data.checkpoint.CheckpointError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from ..checks import check_tensor
from ..primitives.promp import ProMP
from .files import CheckpointError, atomic_write_safetensors, read_safetensors

__all__ = [
    "TrajectoryDataset",
    "Entry",
    "ORIGINS",
    "DATASET_FORMAT",
    "DATASET_SCHEMA",
    "promp_settings",
]

ORIGINS = ("demonstration", "prior", "learned")
DATASET_FORMAT = "protorch.trajectory_dataset"
DATASET_SCHEMA = (
    2  # 2: metadata digests (version 1 files are refused: their settings cannot be verified)
)
_KEYS = ("env", "mean", "var", "label", "origin", "converged", "cost")
_PROMP_KEYS = ("num_dof", "num_basis", "num_steps", "width", "ridge")


def promp_settings(promp) -> dict:
    """The constructor settings of a ProMP (or a dict of them, missing ones taking the
    constructor's defaults) as a plain JSON-able dict."""
    if isinstance(promp, dict):
        missing = [k for k in ("num_dof", "num_basis") if k not in promp]
        if missing:
            raise ValueError(f"ProMP settings lack {missing}")
        out = {k: promp[k] for k in _PROMP_KEYS if promp.get(k) is not None}
        out.setdefault("num_steps", 100)  # the ProMP constructor's defaults
        out.setdefault("width", 1.0 / (int(out["num_basis"]) - 1))
        out.setdefault("ridge", 1e-11)
    else:
        out = {k: getattr(promp, k) for k in _PROMP_KEYS}
    for k in ("num_dof", "num_basis", "num_steps"):
        if k in out:
            out[k] = int(out[k])
    for k in ("width", "ridge"):
        if k in out:
            out[k] = float(out[k])
    return out


@dataclass(frozen=True)
class Entry:
    env: Tensor  # (d,)
    mean: Tensor  # (N,)
    var: Tensor  # (N,)
    label: int
    origin: str
    converged: bool
    cost: float


class TrajectoryDataset:
    """Growable table of environments and their ProMP weight Gaussians.

    Args:
        promp: the :class:`~protorch.ProMP` (or its settings dict) the weights belong to; fixes
            ``N = num_dof * num_basis``.
        env_dim: ``d``, the length of an environment vector.
        task_name: recorded in the checkpoint.
        dtype: of env / mean / var / cost (float64 by default).
    """

    def __init__(
        self, promp, env_dim: int, *, task_name: str = "", dtype: torch.dtype = torch.float64
    ) -> None:
        self.promp_settings = promp_settings(promp)
        if isinstance(env_dim, bool) or int(env_dim) != env_dim or int(env_dim) < 1:
            raise ValueError(f"env_dim must be an int >= 1, got {env_dim!r}")
        self.env_dim = int(env_dim)
        self.task_name = str(task_name)
        self.dtype = dtype
        self.metadata: dict = {}  # extra metadata read from / written to the checkpoint
        self._m = 0
        n, d = self.num_weights, self.env_dim
        self._env = torch.zeros(0, d, dtype=dtype)  # (cap, d)
        self._mean = torch.zeros(0, n, dtype=dtype)  # (cap, N)
        self._var = torch.zeros(0, n, dtype=dtype)  # (cap, N)
        self._label = torch.zeros(0, dtype=torch.long)  # (cap,)
        self._origin = torch.zeros(0, dtype=torch.long)  # (cap,)
        self._converged = torch.zeros(0, dtype=torch.bool)  # (cap,)
        self._cost = torch.zeros(0, dtype=dtype)  # (cap,)

    # ------------------------------------------------------------------ views
    @property
    def num_weights(self) -> int:
        return self.promp_settings["num_dof"] * self.promp_settings["num_basis"]

    def __len__(self) -> int:
        return self._m

    env = property(lambda self: self._env[: self._m], doc="(M, d)")
    mean = property(lambda self: self._mean[: self._m], doc="(M, N)")
    var = property(lambda self: self._var[: self._m], doc="(M, N)")
    label = property(lambda self: self._label[: self._m], doc="(M,) int64")
    origin = property(lambda self: self._origin[: self._m], doc="(M,) int64 index into ORIGINS")
    converged = property(lambda self: self._converged[: self._m], doc="(M,) bool")
    cost = property(lambda self: self._cost[: self._m], doc="(M,) NaN when unknown")

    def __getitem__(self, i: int) -> Entry:
        if not -self._m <= i < self._m:
            raise IndexError(f"entry {i} out of range for {self._m} entries")
        i %= self._m
        return Entry(
            self._env[i].clone(),
            self._mean[i].clone(),
            self._var[i].clone(),
            int(self._label[i]),
            ORIGINS[int(self._origin[i])],
            bool(self._converged[i]),
            float(self._cost[i]),
        )

    def __repr__(self) -> str:
        return (
            f"TrajectoryDataset(task_name={self.task_name!r}, entries={self._m}, env_dim="
            f"{self.env_dim}, "
            f"num_weights={self.num_weights})"
        )

    def make_promp(self, **kwargs):
        """A fresh :class:`~protorch.ProMP` with the recorded settings (``dtype``/``device``
        kwargs)."""

        s = dict(self.promp_settings)
        return ProMP(s.pop("num_dof"), s.pop("num_basis"), **s, **kwargs)

    # ----------------------------------------------------------------- append
    def append(
        self,
        env,
        mean,
        var,
        *,
        label=0,
        origin: str = "learned",
        converged: bool = False,
        cost=math.nan,
    ) -> "TrajectoryDataset":
        """Add one entry (``env (d,)``, ``mean (N,)``, ``var (N,)``) or a batch of ``B``
        (``(B, d)``, ``(B, N)``, ``(B, N)``; ``label``, ``converged``, ``cost`` scalars or
        ``(B,)``).
        Everything is validated before anything is stored."""
        env = check_tensor(env, "env")
        single = env.ndim == 1
        env = env[None] if single else env
        mean = check_tensor(mean, "mean")
        var = check_tensor(var, "var")
        mean, var = (mean[None], var[None]) if single else (mean, var)
        if env.ndim != 2 or env.shape[1] != self.env_dim:
            raise ValueError(
                f"env must be ({self.env_dim},) or (B, {self.env_dim}), got {tuple(env.shape)}"
            )
        b = env.shape[0]
        for x, name in ((mean, "mean"), (var, "var")):
            if x.ndim != 2 or x.shape != (b, self.num_weights):
                raise ValueError(
                    f"{name} must be ({self.num_weights},) or ({b}, {self.num_weights}) "
                    f"to match env, got {tuple(x.shape)}"
                )
        if bool((var < 0).any()):
            raise ValueError(f"var must be >= 0, got a minimum of {float(var.min()):.3g}")
        if origin not in ORIGINS:
            raise ValueError(f"origin must be one of {ORIGINS}, got {origin!r}")
        lab = torch.as_tensor(label).reshape(-1)
        if lab.is_floating_point() or lab.dtype == torch.bool:
            raise ValueError(f"label must be an integer, got {label!r}")
        conv = torch.as_tensor(converged).reshape(-1)
        if conv.dtype != torch.bool:
            raise ValueError(f"converged must be a bool, got {converged!r}")
        cost_t = torch.as_tensor(cost, dtype=self.dtype).reshape(-1)
        if bool(torch.isinf(cost_t).any()):
            raise ValueError("cost must be finite (NaN for unknown)")
        for x, name in ((lab, "label"), (conv, "converged"), (cost_t, "cost")):
            if x.shape[0] not in (1, b):
                raise ValueError(f"{name} must be a scalar or have {b} entries, got {x.shape[0]}")
        self._grow(self._m + b)
        s = slice(self._m, self._m + b)
        self._env[s], self._mean[s], self._var[s] = (
            env.to(self.dtype),
            mean.to(self.dtype),
            var.to(self.dtype),
        )
        self._label[s], self._converged[s], self._cost[s] = lab.to(torch.long), conv, cost_t
        self._origin[s] = ORIGINS.index(origin)
        self._m += b
        return self

    def _grow(self, need: int) -> None:
        cap = self._env.shape[0]
        if need <= cap:
            return
        cap = max(need, 2 * cap, 16)
        for name in ("_env", "_mean", "_var", "_label", "_origin", "_converged", "_cost"):
            old = getattr(self, name)
            new = torch.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[: self._m] = old[: self._m]
            setattr(self, name, new)

    # ----------------------------------------------------------- persistence
    def save(self, path: str | Path, *, extra: dict | None = None) -> Path:
        """Write atomically (temp file in the same directory, fsync, rename). ``extra`` is merged
        into ``self.metadata`` and stored with the checkpoint."""
        if extra:
            self.metadata = {**self.metadata, **extra}
        tensors = {k: getattr(self, k) for k in _KEYS}
        meta = {
            **self.metadata,
            "format": DATASET_FORMAT,
            "schema_version": DATASET_SCHEMA,
            "task_name": self.task_name,
            "promp": self.promp_settings,
            "env_dim": self.env_dim,
            "num_entries": self._m,
            "origins": list(ORIGINS),
        }
        return atomic_write_safetensors(path, tensors, meta)

    @classmethod
    def load(
        cls, path: str | Path, *, promp=None, task_name: str | None = None
    ) -> "TrajectoryDataset":
        """Read a checkpoint written by :meth:`save`.

        ``promp`` (a ProMP or settings dict) and ``task_name``, if given, must match the file's.
        Raises :class:`~protorch.data.checkpoint.CheckpointError` for anything else than a complete,
        intact
        checkpoint of this schema version.
        """
        tensors, meta = read_safetensors(
            path, fmt=DATASET_FORMAT, schema_version=DATASET_SCHEMA, keys=_KEYS
        )
        try:
            settings = promp_settings(meta["promp"])
            env_dim, m, origins = int(meta["env_dim"]), int(meta["num_entries"]), meta["origins"]
            name = str(meta["task_name"])
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f"{path}: incomplete metadata ({exc})") from exc
        if list(origins) != list(ORIGINS):
            raise CheckpointError(
                f"{path} uses origins {origins}, this protorch knows {list(ORIGINS)}"
            )
        if promp is not None:
            want = promp_settings(promp)
            diff = {k: (settings.get(k), v) for k, v in want.items() if settings.get(k) != v}
            if diff:
                raise CheckpointError(
                    f"{path} is for another ProMP: (file, expected) differ in {diff}"
                )
        if task_name is not None and name != task_name:
            raise CheckpointError(f"{path} is for task {name!r}, expected {task_name!r}")
        n = settings["num_dof"] * settings["num_basis"]
        shapes = {
            "env": (m, env_dim),
            "mean": (m, n),
            "var": (m, n),
            "label": (m,),
            "origin": (m,),
            "converged": (m,),
            "cost": (m,),
        }
        for k, shape in shapes.items():
            if tuple(tensors[k].shape) != shape:
                raise CheckpointError(
                    f"{path}: tensor {k!r} has shape {tuple(tensors[k].shape)}, the metadata "
                    f"implies {shape} "
                    f"(N = num_dof * num_basis = {n})"
                )
        if (
            tensors["converged"].dtype != torch.bool
            or tensors["label"].dtype != torch.long
            or tensors["origin"].dtype != torch.long
        ):
            raise CheckpointError(f"{path}: label/origin must be int64 and converged bool")
        for k in ("env", "mean", "var"):
            if not tensors[k].is_floating_point() or not bool(torch.isfinite(tensors[k]).all()):
                raise CheckpointError(f"{path}: tensor {k!r} is not finite floating point")
        if bool((tensors["var"] < 0).any()) or bool(
            ((tensors["origin"] < 0) | (tensors["origin"] >= len(ORIGINS))).any()
        ):
            raise CheckpointError(f"{path}: negative variances or unknown origin codes")
        ds = cls(settings, env_dim, task_name=name, dtype=tensors["mean"].dtype)
        ds.metadata = {
            k: v
            for k, v in meta.items()
            if k
            not in (
                "format",
                "schema_version",
                "task_name",
                "promp",
                "env_dim",
                "num_entries",
                "origins",
                "checksum",
                "digests",
            )
        }
        ds._grow(m)
        for k in _KEYS:
            getattr(ds, "_" + k)[:m] = tensors[k]
        ds._m = m
        return ds
