"""A run folder that tells the truth: whose results it holds, and whether its run finished.

``status.json`` (written atomically) says ``running`` from the start of a run, then ``ok`` or
``failed`` with the error; :func:`check_run_folder` refuses, before any work, a folder that holds
another experiment's results (``metrics.json`` or ``status.json`` naming another experiment), so
a second run cannot replace the first one's files, and clears the temporary files a killed
atomic write left behind.
"""

from __future__ import annotations

import json
import os
import socket
from datetime import datetime, timezone
from pathlib import Path

from ..data.files import atomic_write_bytes, remove_stale_tmp
from .common import write_json

__all__ = ["STATUS_FILE", "CONFIG_FILE", "check_run_folder", "write_status", "write_config"]

STATUS_FILE = "status.json"


def _owner(path: Path) -> str | None:
    """The ``experiment`` a results file names (``None``: no file, or not one of ours)."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        raise ValueError(
            f"{path} exists but is not readable JSON: refusing to run into {path.parent}; "
            "choose another hydra.run.dir"
        ) from None
    return data.get("experiment") if isinstance(data, dict) else None


def check_run_folder(out_dir: str | Path, name: str) -> None:
    """Refuse ``out_dir`` if it holds another experiment's results; then remove stale ``.*.tmp``
    files there. Runs of the same experiment may reuse their folder (``resume=true`` continues
    from its checkpoint; the experiment itself refuses a checkpoint it was not asked to resume)."""
    out_dir = Path(out_dir)
    for file in ("metrics.json", STATUS_FILE):
        owner = _owner(out_dir / file)
        if owner is not None and owner != name:
            raise ValueError(
                f"{out_dir} holds results of experiment {owner!r} ({file}); refusing to write "
                f"{name!r} "
                "there and replace them: choose another hydra.run.dir"
            )
    remove_stale_tmp(out_dir)


def write_status(out_dir: str | Path, name: str, status: str, **extra) -> Path:
    """``status.json`` = ``{"experiment", "status", "host", "pid", "time", **extra}``,
    atomically."""
    path = Path(out_dir) / STATUS_FILE
    write_json(
        path,
        {
            "experiment": name,
            "status": status,
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "time": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
            **extra,
        },
    )
    return path


CONFIG_FILE = "config.yaml"


def write_config(out_dir: str | Path, cfg: dict) -> Path | None:
    """``config.yaml``, the run's resolved settings (what :func:`load_policy` rebuilds the task
    from), atomically, unless the folder has one (the app writes it before the run starts)."""
    from omegaconf import OmegaConf

    path = Path(out_dir) / CONFIG_FILE
    if path.is_file():
        return path
    try:
        text = OmegaConf.to_yaml(OmegaConf.create(cfg))
    except Exception:  # a hand-built config holding objects YAML cannot hold: no config.yaml
        return None
    return atomic_write_bytes(path, text.encode())
