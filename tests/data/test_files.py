"""protorch.data.files: the metadata of a checkpoint is covered by digests (one per top-level
section, the tensor checksum being one of them), checked on load; an edit names its section."""

from __future__ import annotations

import json

import pytest
import safetensors.torch
import torch

from protorch.data.checkpoint import checkpoint_path, load, save_model
from protorch.data.dataset import TrajectoryDataset
from protorch.data.files import (
    META_KEY,
    CheckpointError,
    atomic_write_safetensors,
    read_safetensors,
)
from protorch.gp import load_env_map, make_env_map

PROMP = dict(num_dof=2, num_basis=4, num_steps=30)  # N = 8


def _checkpoint(tmp_path):
    g = torch.Generator().manual_seed(0)
    ds = TrajectoryDataset(PROMP, 2, task_name="particle")
    ds.append(
        torch.rand(6, 2, generator=g, dtype=torch.float64),
        torch.randn(6, 8, generator=g, dtype=torch.float64),
        0.05 + torch.rand(6, 8, generator=g, dtype=torch.float64) / 10,
        origin="demonstration",
    )
    ds.metadata["loop"] = {"version": 1, "step": 3, "signature": "abc"}
    save_model(tmp_path / "run", ds, alpha=2.0, nearest_k=4)
    return checkpoint_path(tmp_path / "run")


def _edit(path, change):
    """Rewrite ``path`` with its metadata passed through ``change`` and the digests left as they
    were."""
    data = path.read_bytes()
    n = int.from_bytes(data[:8], "little")
    meta = json.loads(json.loads(data[8 : 8 + n])["__metadata__"][META_KEY])
    change(meta)
    tensors = safetensors.torch.load(data)
    path.write_bytes(safetensors.torch.save(tensors, metadata={META_KEY: json.dumps(meta)}))


EDITS = {
    "alpha": ("env_map", lambda m: m["env_map"].update(alpha=3.0)),
    "backend": ("env_map", lambda m: m["env_map"].update(backend="gpytorch")),
    "nearest_k": ("env_map", lambda m: m["env_map"]["options"].update(nearest_k=2)),
    "num_steps": ("promp", lambda m: m["promp"].update(num_steps=31)),
    "width": ("promp", lambda m: m["promp"].update(width=0.2)),
    "loop state": ("loop", lambda m: m["loop"].update(step=4)),
    "task name": ("task_name", lambda m: m.update(task_name="other")),
    "new section": ("injected", lambda m: m.update(injected=1)),
    "dropped section": ("loop", lambda m: m.pop("loop")),
}


@pytest.mark.parametrize("name", list(EDITS))
def test_an_edited_metadata_section_is_refused_and_named(tmp_path, name):
    path = _checkpoint(tmp_path)
    load(tmp_path / "run")  # intact: loads
    section, change = EDITS[name]
    _edit(path, change)
    with pytest.raises(CheckpointError, match=f"metadata section '{section}'"):
        load(tmp_path / "run")


def test_an_edited_env_map_file_is_refused(tmp_path):
    g = torch.Generator().manual_seed(1)
    E, MU = (
        torch.rand(5, 2, generator=g, dtype=torch.float64),
        torch.randn(5, 3, generator=g, dtype=torch.float64),
    )
    path = (
        make_env_map("torch", 1.0, nearest_k=3)
        .fit(E, MU, torch.full_like(MU, 0.1))
        .save(tmp_path / "m.safetensors")
    )
    load_env_map(path)
    _edit(path, lambda m: m.update(alpha=5.0))
    with pytest.raises(CheckpointError, match="metadata section 'alpha'"):
        load_env_map(path)


def test_a_checkpoint_without_digests_is_refused_with_the_reason(tmp_path):
    """Files written before the digests carried the tensor checksum only: their settings cannot be
    verified, so they are refused with a message saying so (re-create them)."""
    path = _checkpoint(tmp_path)
    _edit(path, lambda m: (m.pop("digests"), m.update(schema_version=1)))
    with pytest.raises(CheckpointError, match="schema version 1.*no metadata digest"):
        load(tmp_path / "run")


def test_digests_do_not_depend_on_key_order(tmp_path):
    t = {"x": torch.arange(3.0)}
    atomic_write_safetensors(
        tmp_path / "a.safetensors", t, {"format": "f", "schema_version": 1, "s": {"a": 1, "b": 2.5}}
    )
    _edit(tmp_path / "a.safetensors", lambda m: m.update(s={"b": 2.5, "a": 1}))
    got, meta = read_safetensors(tmp_path / "a.safetensors", fmt="f", schema_version=1, keys=["x"])
    assert meta["s"] == {"a": 1, "b": 2.5} and torch.equal(got["x"], t["x"])
