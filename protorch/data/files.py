"""Atomic file writes and verified safetensors files; imports nothing else of protorch.

Every write goes to a temporary file in the same directory, is flushed and fsync-ed, then renamed
over the old file (and the directory fsync-ed), so a process killed at any instant leaves either
the previous or the new complete file. Reading never unpickles: a pickle or a ``torch.save`` zip
is recognised and refused, as are truncated files, checksum mismatches, metadata that does not
match its digests (each top-level section has one), other formats and other schema versions
(:class:`CheckpointError`, a ``ValueError``).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import safetensors.torch
from torch import Tensor

from ..errors import ProtorchError

__all__ = [
    "CheckpointError",
    "atomic_write_bytes",
    "atomic_write_safetensors",
    "read_safetensors",
    "tensor_checksum",
    "metadata_digests",
    "remove_stale_tmp",
    "file_mode",
    "META_KEY",
]

META_KEY = "protorch"


class CheckpointError(ProtorchError, ValueError):
    """A file that is not a complete, uncorrupted protorch checkpoint of the expected kind."""


def file_mode() -> int:
    """The mode ``open()`` gives a new file: ``0o666`` less the process's umask (0644 for the
    usual umask 022). ``mkstemp`` creates 0600 files, which colleagues could not read."""
    try:  # Linux reports the umask without changing it
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def remove_stale_tmp(folder: str | Path) -> list[Path]:
    """Delete the ``.<name>.*.tmp`` files that :func:`atomic_write_bytes` left in ``folder`` when
    its process was killed mid-write; return what was removed. Call it before a run starts
    writing there (a concurrent writer's temporary file would be removed too)."""
    folder = Path(folder)
    removed = []
    if folder.is_dir():
        for tmp in folder.glob(".*.tmp"):
            if tmp.is_file():
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically: temp file in the same directory, fsync, rename.

    The file gets the mode of a plain ``open()`` (:func:`file_mode`, honouring the umask)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, file_mode())
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


def _section_digest(value) -> str:
    """sha256 of a metadata section's canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def metadata_digests(meta: dict) -> dict[str, str]:
    """One digest per top-level metadata section (the tensor ``checksum`` is one of them)."""
    return {k: _section_digest(v) for k, v in meta.items() if k != "digests"}


def atomic_write_safetensors(path: str | Path, tensors: dict[str, Tensor], meta: dict) -> Path:
    """One safetensors file with ``meta`` (JSON) in its header; atomic. Added to ``meta``: the
    tensors' ``checksum`` and ``digests``, one per top-level section (checksum included), so an
    edit of any setting, or of the tensors, is refused on load naming what changed."""
    cpu = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    meta = {k: v for k, v in meta.items() if k != "digests"}
    meta["checksum"] = tensor_checksum(cpu)
    meta["digests"] = metadata_digests(meta)
    data = safetensors.torch.save(cpu, metadata={META_KEY: json.dumps(meta, allow_nan=False)})
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
        raise CheckpointError(
            f"{path} is a Python pickle; protorch never unpickles checkpoints: refusing to load it"
        )
    if len(data) < 10:
        raise CheckpointError(
            f"{path} is truncated or empty ({len(data)} bytes): not a safetensors checkpoint"
        )
    n = int.from_bytes(data[:8], "little")
    if data[8:9] != b"{":
        raise CheckpointError(f"{path} is not a safetensors file (no JSON header)")
    if 8 + n > len(data):
        raise CheckpointError(
            f"{path} is truncated: its header alone needs {8 + n} bytes, the file has {len(data)}"
        )
    return n


def _verify_digests(meta: dict, path: Path) -> None:
    """Refuse metadata whose sections do not match the digests written with them."""
    stored, actual = meta["digests"], metadata_digests(meta)
    for section in sorted(set(stored) | set(actual)):
        if section not in actual:
            raise CheckpointError(
                f"{path}: metadata section {section!r} is missing (its digest is recorded)"
            )
        if section not in stored:
            raise CheckpointError(
                f"{path}: metadata section {section!r} has no digest (added after writing)"
            )
        if stored[section] != actual[section]:
            raise CheckpointError(
                f"{path}: metadata section {section!r} does not match its digest: it was edited "
                "after "
                "writing, and loading it would change the predictions; re-create the file"
            )


def read_safetensors(
    path: str | Path, *, fmt: str, schema_version: int, keys
) -> tuple[dict[str, Tensor], dict]:
    """Read and verify a file written by :func:`atomic_write_safetensors`.

    Checks, in order: it is a complete safetensors file (not a pickle / zip, not truncated), its
    metadata says ``format == fmt``, carries digests and says ``schema_version``, every metadata
    section matches its digest, it holds exactly ``keys``, and the tensor checksum matches. Returns
    ``(tensors on CPU, metadata)``.
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
    raw = (header.get("__metadata__") or {}).get(META_KEY)
    if raw is None:
        raise CheckpointError(
            f"{path} is a safetensors file but not a protorch checkpoint (no metadata)"
        )
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path}: unreadable protorch metadata: {exc}") from exc
    if meta.get("format") != fmt:
        raise CheckpointError(f"{path} holds {meta.get('format')!r}, expected {fmt!r}")
    if not isinstance(meta.get("digests"), dict):
        raise CheckpointError(
            f"{path} has schema version {meta.get('schema_version')!r} and no metadata digest, so "
            "its "
            f"settings cannot be verified; this protorch reads version {schema_version} only: "
            "re-create it"
        )
    if meta.get("schema_version") != schema_version:
        raise CheckpointError(
            f"{path} has schema version {meta.get('schema_version')!r}; this protorch reads "
            f"version {schema_version} only"
        )
    _verify_digests(meta, path)
    if set(tensors) != set(keys):
        raise CheckpointError(f"{path} holds tensors {sorted(tensors)}, expected {sorted(keys)}")
    if tensor_checksum(tensors) != meta.get("checksum"):
        raise CheckpointError(
            f"{path} is corrupted: the tensor checksum does not match its metadata"
        )
    return tensors, meta
