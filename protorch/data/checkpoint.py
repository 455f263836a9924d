"""Checkpoints without pickle, and a trained run as a plain torch module.

Layout of a run's checkpoint (written by :func:`save_model`, read by :func:`load`)::

    <run_dir>/checkpoint/dataset.safetensors

one safetensors file holding the :class:`~protorch.data.dataset.TrajectoryDataset` tensors
(``env (M, d)``, ``mean (M, N)``, ``var (M, N)``, ``label``, ``origin``, ``converged``, ``cost``
``(M,)``) and, in the header's ``__metadata__`` under the key ``"protorch"``, a JSON object::

    {"format": "protorch.trajectory_dataset", "schema_version": 2, "task_name": "...",
     "promp": {"num_dof", "num_basis", "num_steps", "width", "ridge"}, "env_dim": d,
     "num_entries": M, "origins": [...], "checksum": "<sha256 of the tensors>",
     "env_map": {"backend": "torch", "alpha": 1.0, "options": {...},
                 "include_unconverged": false},
     "digests": {"<section>": "<sha256 of its canonical JSON>", ...}}

``digests`` holds one digest per other top-level section (``checksum`` included); :func:`load`
refuses a file whose sections do not match them, naming the section (an edited ``alpha`` or ProMP
width would otherwise load silently and change the predictions). Schema version 1 files, written
before the digests, are refused with a message saying so: re-create them.

Data and metadata live in one file so that a single atomic ``os.replace`` publishes both:
every write goes to a temporary file in the same directory, is flushed and fsync-ed, then
renamed over the old file (and the directory fsync-ed), so a process killed at any instant leaves
either the previous or the new complete checkpoint. Reading never unpickles: a pickle or a
``torch.save`` zip is recognised and refused, as are truncated files, checksum mismatches, other
formats and other schema versions (:class:`CheckpointError`, a ``ValueError``).
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from ..gp import make_env_map
from ..gp.model import EnvToProMP
from .dataset import ORIGINS, TrajectoryDataset
from .files import CheckpointError

__all__ = [
    "CheckpointError",
    "EnvToProMP",
    "load",
    "save_model",
    "checkpoint_path",
    "CHECKPOINT_DIR",
    "DATASET_FILE",
]

CHECKPOINT_DIR = "checkpoint"
DATASET_FILE = "dataset.safetensors"


def checkpoint_path(run_dir_or_checkpoint: str | Path) -> Path:
    """``<run_dir>`` -> ``<run_dir>/checkpoint/dataset.safetensors``; a ``.safetensors`` path or a
    ``checkpoint`` directory is resolved to the file it names or holds."""
    p = Path(run_dir_or_checkpoint)
    if p.suffix == ".safetensors":
        return p
    if (p / DATASET_FILE).is_file() and not (p / CHECKPOINT_DIR / DATASET_FILE).is_file():
        return p / DATASET_FILE
    return p / CHECKPOINT_DIR / DATASET_FILE


def save_model(
    run_dir_or_checkpoint: str | Path,
    dataset,
    *,
    backend: str = "torch",
    alpha: float,
    include_unconverged: bool = False,
    **options,
) -> Path:
    """Write ``dataset`` with the environment-map settings that :func:`load` rebuilds it with.

    ``options`` are the map's JSON-serialisable options (``nearest_k``, ...); ``dtype`` and
    ``device`` are chosen at load time. Learned entries whose PRO run did not converge are left
    out of the map unless ``include_unconverged`` (demonstrations and priors always count).
    Atomic: call it after every iteration of a loop; a crash leaves the previous checkpoint.
    """
    if "dtype" in options or "device" in options:
        raise ValueError("dtype and device are not saved; pass them to load()")
    make_env_map(backend, alpha, **options)  # validates backend, alpha and options now
    settings = {
        "backend": backend,
        "alpha": float(alpha),
        "options": options,
        "include_unconverged": bool(include_unconverged),
    }
    try:
        json.dumps(settings, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"environment-map options must be JSON-serialisable: {exc}") from exc
    return dataset.save(checkpoint_path(run_dir_or_checkpoint), extra={"env_map": settings})


def load(
    run_dir_or_checkpoint: str | Path,
    *,
    device=None,
    dtype: torch.dtype = torch.float64,
    backend: str | None = None,
    promp=None,
) -> EnvToProMP:
    """Load a run saved by :func:`save_model` as an :class:`EnvToProMP` (no Hydra needed).

    Args:
        run_dir_or_checkpoint: the run directory, its ``checkpoint`` folder or the file.
        device, dtype: where and in which precision the GPs run.
        backend: override the saved GP backend.
        promp: if given (a ProMP or its settings dict), refuse a checkpoint of another size.
    """
    path = checkpoint_path(run_dir_or_checkpoint)
    ds = TrajectoryDataset.load(path, promp=promp)
    settings = ds.metadata.get("env_map")
    if not settings:
        raise CheckpointError(
            f"{path} holds no environment-map settings: write it with protorch.save_model"
        )
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
