"""TrajectoryDataset: entries, atomic checkpoints that survive SIGKILL, refusal of bad files."""

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch

from protorch import ProMP
from protorch.data.dataset import ORIGINS, TrajectoryDataset
from protorch.data.files import CheckpointError

PROMP = dict(num_dof=2, num_basis=5, num_steps=50)  # N = 10


def _dataset(m=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    ds = TrajectoryDataset(PROMP, 3, task_name="window")
    for i in range(m):
        ds.append(
            torch.rand(3, generator=g, dtype=torch.float64),
            torch.randn(10, generator=g, dtype=torch.float64),
            torch.rand(10, generator=g, dtype=torch.float64),
            label=i % 2,
            origin=ORIGINS[i % 3],
            converged=bool(i % 2),
            cost=float(i) if i % 3 else float("nan"),
        )
    return ds


def _same(a, b):
    assert len(a) == len(b) and a.task_name == b.task_name and a.promp_settings == b.promp_settings
    for k in ("env", "mean", "var", "label", "origin", "converged"):
        assert torch.equal(getattr(a, k), getattr(b, k)), k
    assert torch.equal(a.cost.isnan(), b.cost.isnan())
    assert torch.equal(a.cost.nan_to_num(), b.cost.nan_to_num())


def test_append_and_entries():
    ds = _dataset(5)
    assert len(ds) == 5 and ds.mean.shape == (5, 10) and ds.env.shape == (5, 3)
    e = ds[4]
    assert (
        e.origin == "prior"
        and ds[2].origin == "learned"
        and e.label == 0
        and e.converged is False
        and e.cost == 4.0
    )
    assert torch.equal(e.mean, ds.mean[4]) and torch.equal(ds[-1].env, ds.env[4])
    ds.append(
        torch.zeros(4, 3),
        torch.zeros(4, 10),
        torch.ones(4, 10),
        label=torch.tensor([0, 1, 2, 3]),
        origin="prior",
        converged=True,
    )  # a batch
    assert len(ds) == 9 and ds.label[-4:].tolist() == [0, 1, 2, 3] and bool(ds.converged[-4:].all())
    assert ds[-1].origin == "prior" and ds.cost[-1].isnan()
    with pytest.raises(IndexError):
        ds[9]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(env=torch.zeros(2)), "env"),
        (dict(mean=torch.zeros(9)), "mean"),
        (dict(var=-torch.ones(10)), "var"),
        (dict(var=torch.full((10,), float("nan"))), "NaN"),
        (dict(origin="dreamt"), "origin"),
        (dict(label=0.5), "label"),
        (dict(converged=1), "converged"),
        (dict(cost=float("inf")), "cost"),
    ],
)
def test_append_rejects_bad_input_without_change(kwargs, match):
    ds = _dataset(3)
    args = dict(env=torch.zeros(3), mean=torch.zeros(10), var=torch.ones(10))
    args.update(kwargs)
    env, mean, var = args.pop("env"), args.pop("mean"), args.pop("var")
    with pytest.raises(ValueError, match=match):
        ds.append(env, mean, var, **args)
    _same(ds, _dataset(3))


def test_save_load_roundtrip(tmp_path):
    ds = _dataset(40)  # grows the storage several times
    ds.save(tmp_path / "ckpt" / "dataset.safetensors", extra={"note": "hi"})
    back = TrajectoryDataset.load(
        tmp_path / "ckpt" / "dataset.safetensors", promp=ProMP(**PROMP), task_name="window"
    )
    _same(ds, back)
    assert back.metadata["note"] == "hi"
    assert [f for f in os.listdir(tmp_path / "ckpt")] == [
        "dataset.safetensors"
    ]  # no temp file left
    empty = TrajectoryDataset(PROMP, 3)
    empty.save(tmp_path / "empty.safetensors")
    assert len(TrajectoryDataset.load(tmp_path / "empty.safetensors")) == 0


def test_refuses_bad_files(tmp_path):
    p = tmp_path / "d.safetensors"
    _dataset(8).save(p)
    data = p.read_bytes()
    # another ProMP size, another task
    with pytest.raises(CheckpointError, match="another ProMP"):
        TrajectoryDataset.load(p, promp=ProMP(2, 6, 50))
    with pytest.raises(CheckpointError, match="task"):
        TrajectoryDataset.load(p, task_name="arm")
    # truncated anywhere: header or data
    for cut in (0, 5, 100, len(data) // 2, len(data) - 1):
        (tmp_path / "t.safetensors").write_bytes(data[:cut])
        with pytest.raises(CheckpointError, match="truncated|corrupted|not a safetensors"):
            TrajectoryDataset.load(tmp_path / "t.safetensors")
    # a flipped data byte
    flipped = bytearray(data)
    flipped[-3] ^= 0xFF
    (tmp_path / "f.safetensors").write_bytes(bytes(flipped))
    with pytest.raises(CheckpointError, match="checksum"):
        TrajectoryDataset.load(tmp_path / "f.safetensors")
    # a pickle disguised as a checkpoint (raw pickle and torch.save zip)
    import pickle

    (tmp_path / "p.safetensors").write_bytes(pickle.dumps({"env": [1, 2]}))
    with pytest.raises(CheckpointError, match="pickle"):
        TrajectoryDataset.load(tmp_path / "p.safetensors")
    torch.save({"env": torch.zeros(2)}, tmp_path / "z.safetensors")
    with pytest.raises(CheckpointError, match="pickle"):
        TrajectoryDataset.load(tmp_path / "z.safetensors")
    # foreign schema version / foreign format
    from protorch.data.files import atomic_write_safetensors, read_safetensors

    tensors, meta = read_safetensors(
        p,
        fmt="protorch.trajectory_dataset",
        schema_version=2,
        keys=("env", "mean", "var", "label", "origin", "converged", "cost"),
    )
    atomic_write_safetensors(tmp_path / "v3.safetensors", tensors, {**meta, "schema_version": 3})
    with pytest.raises(CheckpointError, match="schema version 3"):
        TrajectoryDataset.load(tmp_path / "v3.safetensors")
    atomic_write_safetensors(
        tmp_path / "map.safetensors", tensors, {**meta, "format": "protorch.env_map"}
    )
    with pytest.raises(CheckpointError, match="expected 'protorch.trajectory_dataset'"):
        TrajectoryDataset.load(tmp_path / "map.safetensors")
    # metadata that lies about the ProMP size
    atomic_write_safetensors(
        tmp_path / "n.safetensors", tensors, {**meta, "promp": {**meta["promp"], "num_basis": 6}}
    )
    with pytest.raises(CheckpointError, match="shape"):
        TrajectoryDataset.load(tmp_path / "n.safetensors")
    with pytest.raises(FileNotFoundError):
        TrajectoryDataset.load(tmp_path / "missing.safetensors")


_WRITER = textwrap.dedent(
    """
    import sys, torch
    from protorch.data.dataset import TrajectoryDataset
    path = sys.argv[1]
    try:
        ds = TrajectoryDataset.load(path)          # resume after a crash
    except FileNotFoundError:
        ds = TrajectoryDataset(dict(num_dof=2, num_basis=5, num_steps=50), 3, task_name="crash")
    print("start", len(ds), flush=True)
    while True:
        i = len(ds)
        ds.append(torch.full((3,), float(i), dtype=torch.float64), torch.full((10,), float(i), dtype=torch.float64),
                  torch.full((10,), 1.0 + i, dtype=torch.float64), label=i % 3, converged=True, cost=float(i))
        ds.save(path)
        print(i, flush=True)                        # entry i is in a checkpoint on disk
    """
)


# the writer imports this checkout's protorch, not whichever one the interpreter has installed
_THIS_REPO = {
    **os.environ,
    "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[2]), *filter(None, [os.environ.get("PYTHONPATH")])]
    ),
}


@pytest.mark.slow
def test_sigkill_at_random_moments_leaves_a_complete_checkpoint(tmp_path):
    path = tmp_path / "run" / "checkpoint" / "dataset.safetensors"
    script = tmp_path / "writer.py"
    script.write_text(_WRITER)
    rng = random.Random(0)
    last_saved = -1
    for _ in range(4):
        proc = subprocess.Popen(
            [sys.executable, str(script), str(path)],
            stdout=subprocess.PIPE,
            text=True,
            env=_THIS_REPO,
        )
        try:
            assert proc.stdout.readline().startswith("start")
            time.sleep(
                rng.uniform(0.05, 0.4)
            )  # then kill at an arbitrary instant, mid-write or not
            proc.send_signal(signal.SIGKILL)
            out = proc.communicate()[0]
        finally:
            proc.kill()
        acked = [int(x) for x in out.split()]
        if acked:
            last_saved = max(last_saved, acked[-1])
        ds = TrajectoryDataset.load(path)
        m = len(ds)
        assert m >= last_saved + 1, f"entries acknowledged as saved were lost: {m} <= {last_saved}"
        ar = torch.arange(m, dtype=torch.float64)
        assert (
            torch.equal(ds.env[:, 0], ar)
            and torch.equal(ds.mean[:, 9], ar)
            and torch.equal(ds.var[:, 0], ar + 1)
        )
        assert torch.equal(ds.label, torch.arange(m) % 3) and ds.task_name == "crash"
    assert last_saved >= 1  # the writer did make progress between kills
