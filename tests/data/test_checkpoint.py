"""protorch.data.checkpoint: a trained run loads as a plain torch module; checkpoints are atomic
and safe."""

import numpy as np
import pytest
import torch

from protorch import ProMP
from protorch.data.checkpoint import checkpoint_path, load, save_model
from protorch.data.dataset import TrajectoryDataset
from protorch.data.files import CheckpointError, atomic_write_bytes, atomic_write_safetensors
from protorch.gp import make_env_map
from protorch.gp.model import EnvToProMP

PROMP = dict(num_dof=2, num_basis=4, num_steps=30)  # N = 8


def _run(tmp_path, **gp):
    g = torch.Generator().manual_seed(0)
    ds = TrajectoryDataset(PROMP, 2, task_name="particle")
    E = torch.rand(12, 2, generator=g, dtype=torch.float64)
    MU = torch.randn(12, 8, generator=g, dtype=torch.float64)
    VAR = 0.01 + 0.1 * torch.rand(12, 8, generator=g, dtype=torch.float64)
    ds.append(E[:4], MU[:4], VAR[:4], origin="demonstration")
    ds.append(
        E[4:8],
        MU[4:8],
        VAR[4:8],
        origin="learned",
        converged=True,
        label=torch.tensor([0, 1, 0, 1]),
    )
    ds.append(E[8:], MU[8:], VAR[8:], origin="learned", converged=False)  # excluded from the map
    save_model(tmp_path / "run", ds, **gp)
    return ds, E, MU, VAR


def test_load_run_dir_gives_the_env_map_of_the_usable_entries(tmp_path):
    ds, E, MU, VAR = _run(tmp_path, backend="torch", alpha=2.0, nearest_k=5)
    assert (
        checkpoint_path(tmp_path / "run") == tmp_path / "run" / "checkpoint" / "dataset.safetensors"
    )
    model = load(tmp_path / "run")
    assert isinstance(model, EnvToProMP) and isinstance(model, torch.nn.Module)
    assert (
        model.task_name == "particle"
        and model.promp.num_weights == 8
        and model.promp.num_steps == 30
    )
    keep = torch.tensor([1] * 8 + [0] * 4, dtype=torch.bool)
    labels = ds.label[keep]
    ref = make_env_map("torch", 2.0, nearest_k=5).fit(E[keep], MU[keep], VAR[keep], labels)
    Q = torch.rand(3, 2, dtype=torch.float64)
    lab = torch.tensor([0, 1, 0])
    mu, var = model(Q, lab)
    rmu, rvar = ref.predict(Q, lab)
    assert (
        mu.shape == (3, 8)
        and torch.allclose(mu, rmu, atol=1e-12)
        and torch.allclose(var, rvar, atol=1e-12)
    )
    traj = model.promp.trajectory(mu)
    assert traj.shape == (3, 30, 2)
    assert torch.allclose(model.mean_trajectory(Q, lab), traj)
    # the same file, named three ways, and another backend give the same map
    for where in (
        tmp_path / "run" / "checkpoint",
        tmp_path / "run" / "checkpoint" / "dataset.safetensors",
    ):
        assert torch.allclose(load(where)(Q, lab)[0], mu, atol=1e-12)
    assert torch.allclose(load(tmp_path / "run", backend="gpytorch")(Q, lab)[0], mu, atol=1e-8)


def test_include_unconverged_keeps_every_learned_entry(tmp_path):
    ds, E, MU, VAR = _run(tmp_path, backend="torch", alpha=2.0, include_unconverged=True)
    model = load(tmp_path / "run")
    assert (
        model.env_map.num_points == 12
    )  # demonstrations, converged and unconverged learned entries
    ref = make_env_map("torch", 2.0).fit(E, MU, VAR, ds.label)
    Q = torch.rand(3, 2, dtype=torch.float64)
    lab = torch.tensor([0, 1, 0])
    assert torch.allclose(model(Q, lab)[0], ref.predict(Q, lab)[0], atol=1e-12)


def test_load_checks_promp_and_settings(tmp_path):
    _run(tmp_path, backend="gpytorch", alpha=1.0)
    with pytest.raises(CheckpointError, match="another ProMP"):
        load(tmp_path / "run", promp=ProMP(2, 5, 30))
    assert load(tmp_path / "run", promp=ProMP(**PROMP)).env_map.backend == "gpytorch"
    ds = TrajectoryDataset(PROMP, 2)
    ds.append(torch.zeros(2), torch.zeros(8), torch.ones(8))
    ds.save(tmp_path / "plain.safetensors")
    with pytest.raises(CheckpointError, match="environment-map settings"):
        load(tmp_path / "plain.safetensors")
    with pytest.raises(FileNotFoundError):
        load(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="alpha"):
        save_model(tmp_path / "bad", ds, alpha=0.0)
    with pytest.raises(TypeError):
        save_model(tmp_path / "bad", ds, alpha=1.0, bogus=1)


def test_float32_load_and_no_hydra(tmp_path):
    from pathlib import Path

    import protorch.data.checkpoint
    import protorch.data.dataset
    import protorch.gp

    _run(tmp_path, alpha=1.0)
    model = load(tmp_path / "run", dtype=torch.float32)
    mu, var = model(torch.zeros(1, 2, dtype=torch.float32), labels=1)
    assert mu.dtype == torch.float32 and bool(torch.isfinite(var).all()) and bool((var > 0).all())
    with pytest.raises(ValueError, match="several labels"):
        model(torch.zeros(1, 2, dtype=torch.float32))
    # a trained run is usable without Hydra: library code never imports it
    files = [
        Path(protorch.data.checkpoint.__file__),
        Path(protorch.data.dataset.__file__),
        *Path(protorch.gp.__file__).parent.glob("*.py"),
    ]
    assert not [
        f.name for f in files if "import hydra" in f.read_text() or "from hydra" in f.read_text()
    ]


def test_atomic_write_replaces_whole_file(tmp_path):
    p = tmp_path / "x.bin"
    atomic_write_bytes(p, b"a" * 1000)
    atomic_write_bytes(p, b"b" * 10)
    assert p.read_bytes() == b"b" * 10
    assert sorted(x.name for x in tmp_path.iterdir()) == ["x.bin"]
    np.testing.assert_equal(len(list(tmp_path.glob(".*.tmp"))), 0)


@pytest.mark.parametrize("first_byte", [0x80, ord("P")])
def test_header_lengths_that_look_like_a_pickle_or_zip_still_load(tmp_path, first_byte):
    """The first byte of a safetensors file is the low byte of its header length: 0x80 (a pickle's
    first byte) or 'P' (a zip's) must not make a valid checkpoint unreadable."""
    from protorch.data.files import read_safetensors

    tensors = {"x": torch.arange(3.0)}
    path = tmp_path / "c.safetensors"
    for pad in range(300):
        atomic_write_safetensors(
            path, tensors, {"format": "f", "schema_version": 1, "pad": "#" * pad}
        )
        if path.read_bytes()[0] == first_byte:
            break
    else:  # pragma: no cover
        pytest.fail("no padding gave the wanted header length")
    got, meta = read_safetensors(path, fmt="f", schema_version=1, keys=["x"])
    assert torch.equal(got["x"], tensors["x"]) and meta["pad"] == "#" * pad
