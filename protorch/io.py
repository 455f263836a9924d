"""Checkpoints without pickle, and a trained run as a plain torch module.

Layout of a run's checkpoint (written by :func:`save_model`, read by :func:`load`)::

    <run_dir>/checkpoint/dataset.safetensors

one safetensors file holding the :class:`~protorch.dataset.TrajectoryDataset` tensors
(``env (M, d)``, ``mean (M, N)``, ``var (M, N)``, ``label``, ``origin``, ``converged``, ``cost``
``(M,)``) and, in the header's ``__metadata__`` under the key ``"protorch"``, a JSON object::

    {"format": "protorch.trajectory_dataset", "schema_version": 1, "task_name": "...",
     "promp": {"num_dof", "num_basis", "num_steps", "width", "ridge"}, "env_dim": d,
     "num_entries": M, "origins": [...], "checksum": "<sha256 of the tensors>",
     "env_map": {"backend": "torch", "alpha": 1.0, "options": {...},
                 "include_unconverged": false}}

Data and metadata live in one file so that a single atomic ``os.replace`` publishes both:
every write goes to a temporary file in the same directory, is flushed and fsync-ed, then
renamed over the old file (and the directory fsync-ed), so a process killed at any instant leaves
either the previous or the new complete checkpoint. Reading never unpickles: a pickle or a
``torch.save`` zip is recognised and refused, as are truncated files, checksum mismatches, other
formats and other schema versions (:class:`CheckpointError`, a ``ValueError``).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import safetensors.torch
import torch
from torch import Tensor, nn

__all__ = [
    "CheckpointError", "EnvToProMP", "load", "save_model", "checkpoint_path",
    "atomic_write_bytes", "atomic_write_safetensors", "read_safetensors",
    "CHECKPOINT_DIR", "DATASET_FILE",
]

CHECKPOINT_DIR = "checkpoint"
DATASET_FILE = "dataset.safetensors"
_META_KEY = "protorch"


class CheckpointError(ValueError):
    """A file that is not a complete, uncorrupted protorch checkpoint of the expected kind."""


# --------------------------------------------------------------------------- low level
def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically: temp file in the same directory, fsync, rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    try:  # make the rename itself durable (POSIX; not possible on Windows)
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass
    return path


def tensor_checksum(tensors: dict[str, Tensor]) -> str:
    """sha256 over names, dtypes, shapes and bytes of the tensors, in name order."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().to("cpu").contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def atomic_write_safetensors(path: str | Path, tensors: dict[str, Tensor], meta: dict) -> Path:
    """One safetensors file with ``meta`` (JSON, a checksum added) in its header; atomic."""
    cpu = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    meta = {**meta, "checksum": tensor_checksum(cpu)}
    data = safetensors.torch.save(cpu, metadata={_META_KEY: json.dumps(meta, allow_nan=False)})
    return atomic_write_bytes(path, data)


def _sniff(data: bytes, path: Path) -> int:
    """Refuse anything that is not a complete safetensors file; return its header length.

    The safetensors layout (8-byte little-endian header length, then a JSON object) is checked
    first: its length bytes can be anything, so a header of 128 + 256 k bytes starts with the
    byte ``0x80`` like a pickle, and one of 0x4B50 + 65536 k bytes with ``PK`` like a zip."""
    if len(data) >= 10 and data[8:9] == b"{":
        n = int.from_bytes(data[:8], "little")
        if 8 + n <= len(data):
            return n
    if data[:2] == b"PK":
        raise CheckpointError(
            f"{path} is a zip archive (the torch.save format, which contains a pickle); "
            "protorch never unpickles checkpoints: refusing to load it"
        )
    if data[:1] == b"\x80":
        raise CheckpointError(f"{path} is a Python pickle; protorch never unpickles checkpoints: refusing to load it")
    if len(data) < 10:
        raise CheckpointError(f"{path} is truncated or empty ({len(data)} bytes): not a safetensors checkpoint")
    n = int.from_bytes(data[:8], "little")
    if data[8:9] != b"{":
        raise CheckpointError(f"{path} is not a safetensors file (no JSON header)")
    if 8 + n > len(data):
        raise CheckpointError(
            f"{path} is truncated: its header alone needs {8 + n} bytes, the file has {len(data)}"
        )
    return n


def read_safetensors(path: str | Path, *, fmt: str, schema_version: int, keys) -> tuple[dict[str, Tensor], dict]:
    """Read and verify a file written by :func:`atomic_write_safetensors`.

    Checks, in order: it is a complete safetensors file (not a pickle / zip, not truncated), its
    metadata says ``format == fmt`` and ``schema_version``, it holds exactly ``keys``, and the
    checksum matches. Returns ``(tensors on CPU, metadata)``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint file at {path}")
    data = path.read_bytes()
    n = _sniff(data, path)
    try:
        header = json.loads(data[8 : 8 + n])
        tensors = safetensors.torch.load(data)
    except Exception as exc:  # safetensors' own error types vary between versions
        raise CheckpointError(f"{path} is corrupted or truncated: {exc}") from exc
    raw = (header.get("__metadata__") or {}).get(_META_KEY)
    if raw is None:
        raise CheckpointError(f"{path} is a safetensors file but not a protorch checkpoint (no metadata)")
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path}: unreadable protorch metadata: {exc}") from exc
    if meta.get("format") != fmt:
        raise CheckpointError(f"{path} holds {meta.get('format')!r}, expected {fmt!r}")
    if meta.get("schema_version") != schema_version:
        raise CheckpointError(
            f"{path} has schema version {meta.get('schema_version')!r}; this protorch reads "
            f"version {schema_version} only"
        )
    if set(tensors) != set(keys):
        raise CheckpointError(f"{path} holds tensors {sorted(tensors)}, expected {sorted(keys)}")
    if tensor_checksum(tensors) != meta.get("checksum"):
        raise CheckpointError(f"{path} is corrupted: the tensor checksum does not match its metadata")
    return tensors, meta


def checkpoint_path(run_dir_or_checkpoint: str | Path) -> Path:
    """``<run_dir>`` -> ``<run_dir>/checkpoint/dataset.safetensors``; a ``.safetensors`` path or a
    ``checkpoint`` directory is resolved to the file it names or holds."""
    p = Path(run_dir_or_checkpoint)
    if p.suffix == ".safetensors":
        return p
    if (p / DATASET_FILE).is_file() and not (p / CHECKPOINT_DIR / DATASET_FILE).is_file():
        return p / DATASET_FILE
    return p / CHECKPOINT_DIR / DATASET_FILE


# ---------------------------------------------------------------------- run as a module
class EnvToProMP(nn.Module):
    """A trained run: environments ``(B, d)`` -> ProMP weight Gaussians ``(mu (B, N), var (B, N))``.

    ``model.promp.trajectory(mu)`` gives the mean trajectories ``(B, T, D)``;
    ``model.task_name`` names the task the run solved.
    """

    def __init__(self, promp, env_map, task_name: str = "") -> None:
        super().__init__()
        if promp.num_weights != env_map.num_weights:
            raise ValueError(
                f"the ProMP has {promp.num_weights} weights but the environment map predicts {env_map.num_weights}"
            )
        self.promp = promp
        self.env_map = env_map
        self.task_name = str(task_name)

    @property
    def env_dim(self) -> int:
        return self.env_map.env_dim

    def forward(self, env: Tensor, labels=None) -> tuple[Tensor, Tensor]:
        return self.env_map.predict(env, labels)

    def mean_trajectory(self, env: Tensor, labels=None) -> Tensor:
        """``(B, d)`` -> mean trajectories ``(B, T, D)``."""
        return self.promp.trajectory(self.env_map.predict_mean(env, labels))

    def extra_repr(self) -> str:
        return f"task_name={self.task_name!r}, env_dim={self.env_dim}"


def save_model(run_dir_or_checkpoint: str | Path, dataset, *, backend: str = "torch", alpha: float,
               include_unconverged: bool = False, **options) -> Path:
    """Write ``dataset`` with the environment-map settings that :func:`load` rebuilds it with.

    ``options`` are the map's JSON-serialisable options (``nearest_k``, ...); ``dtype`` and
    ``device`` are chosen at load time. Learned entries whose PRO run did not converge are left
    out of the map unless ``include_unconverged`` (demonstrations and priors always count).
    Atomic: call it after every iteration of a loop; a crash leaves the previous checkpoint.
    """
    from .gp import make_env_map

    if "dtype" in options or "device" in options:
        raise ValueError("dtype and device are not saved; pass them to load()")
    make_env_map(backend, alpha, **options)  # validates backend, alpha and options now
    settings = {"backend": backend, "alpha": float(alpha), "options": options,
                "include_unconverged": bool(include_unconverged)}
    try:
        json.dumps(settings, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"environment-map options must be JSON-serialisable: {exc}") from exc
    return dataset.save(checkpoint_path(run_dir_or_checkpoint), extra={"env_map": settings})


def load(run_dir_or_checkpoint: str | Path, *, device=None, dtype: torch.dtype = torch.float64,
         backend: str | None = None, promp=None) -> EnvToProMP:
    """Load a run saved by :func:`save_model` as an :class:`EnvToProMP` (no Hydra needed).

    Args:
        run_dir_or_checkpoint: the run directory, its ``checkpoint`` folder or the file.
        device, dtype: where and in which precision the GPs run.
        backend: override the saved GP backend.
        promp: if given (a ProMP or its settings dict), refuse a checkpoint of another size.
    """
    from .dataset import TrajectoryDataset, ORIGINS
    from .gp import make_env_map

    path = checkpoint_path(run_dir_or_checkpoint)
    ds = TrajectoryDataset.load(path, promp=promp)
    settings = ds.metadata.get("env_map")
    if not settings:
        raise CheckpointError(f"{path} holds no environment-map settings: write it with protorch.io.save_model")
    keep = ds.origin != ORIGINS.index("learned")  # (M,) demonstrations and priors always count
    if settings.get("include_unconverged", False):
        keep = torch.ones_like(keep)  # every learned entry too
    else:
        keep = keep | ds.converged  # learned entries only where their run converged
    if not bool(keep.any()):
        raise CheckpointError(f"{path} holds no entry usable by the environment map")
    chosen = backend or settings["backend"]
    opts = dict(settings.get("options", {}))
    if chosen != settings["backend"]:
        opts = {"nearest_k": opts.get("nearest_k")}
    env_map = make_env_map(chosen, settings["alpha"], dtype=dtype, device=device, **opts)
    env_map.fit(ds.env[keep], ds.mean[keep], ds.var[keep], ds.label[keep])
    model = EnvToProMP(ds.make_promp(dtype=dtype, device=device), env_map, ds.task_name)
    return model.eval()
