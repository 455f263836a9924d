"""The loop's run state: the caller's data set is left alone, a run directory that cannot be
written is refused before any work, the signature and the checkpoint round trip."""

from __future__ import annotations

import os

import pytest
import torch

from protorch import make_env_map
from protorch.data.dataset import TrajectoryDataset
from protorch.loop import LoopSettings, RunState, save_model
from protorch.loop.state import run_signature, writable_folder

from .test_loop import loop, setup


def test_the_callers_data_set_is_left_alone_and_two_calls_agree():
    task, promp, ds = setup()
    before = (len(ds), ds.env.clone(), ds.mean.clone(), ds.var.clone(), dict(ds.metadata))
    first = loop(task, promp, ds, num_envs=6, batch_size=3, add_only="all")
    assert (
        len(ds) == before[0] == 4 and len(first.dataset) == 4 + 6
    )  # the grown one is the result's
    assert (
        torch.equal(ds.env, before[1])
        and torch.equal(ds.mean, before[2])
        and torch.equal(ds.var, before[3])
    )
    assert ds.metadata == before[4]
    second = loop(task, promp, ds, num_envs=6, batch_size=3, add_only="all")  # the same start again
    assert len(ds) == 4 and second.tried == first.tried
    assert torch.equal(second.dataset.mean, first.dataset.mean) and torch.equal(
        second.dataset.var, first.dataset.var
    )
    assert [r.get("success") for r in second.metrics] == [r.get("success") for r in first.metrics]
    assert second.dataset is not ds and first.dataset is not second.dataset


def _read_only_dir(tmp_path):
    """A folder chmod'ed 0o500, or a skip where that does not stop writing (running as root)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        (ro / "probe").write_text("x")
    except PermissionError:
        return ro
    (ro / "probe").unlink()
    ro.chmod(0o700)
    pytest.skip("chmod does not stop writing here (root)")


@pytest.mark.parametrize("sub", ["", "run"])
def test_a_read_only_run_dir_is_refused_before_any_work(tmp_path, sub):
    ro = _read_only_dir(tmp_path)
    try:
        task, promp, ds = setup()
        made = []

        def env_map():
            made.append(1)
            return make_env_map("torch", 1.0)

        run_dir = ro / sub if sub else ro
        with pytest.raises(PermissionError, match=f"run_dir: cannot write in {run_dir}"):
            loop(task, promp, ds, run_dir=run_dir, env_map=env_map)
        assert not made  # refused before the map was built or anything was fitted
        assert sorted(p.name for p in ro.iterdir()) == []  # and no probe left behind
    finally:
        ro.chmod(0o700)


def test_writable_folder_creates_the_folder_and_leaves_no_probe(tmp_path):
    run = tmp_path / "a" / "b"
    assert writable_folder(run) == run and run.is_dir()
    assert list(run.iterdir()) == []
    (run / "checkpoint").mkdir()
    writable_folder(run)
    assert list((run / "checkpoint").iterdir()) == []


def test_a_read_only_checkpoint_folder_is_refused_too(tmp_path):
    ro = _read_only_dir(tmp_path)
    ro.chmod(0o700)
    run = tmp_path / "run"
    (run / "checkpoint").mkdir(parents=True)
    (run / "checkpoint").chmod(0o500)
    try:
        with pytest.raises(PermissionError, match="checkpoint"):
            writable_folder(run)
    finally:
        (run / "checkpoint").chmod(0o700)


def test_checkpoint_round_trip_through_resume(tmp_path):
    _, promp, ds = setup()
    settings = LoopSettings(num_envs=4, batch_size=2, seed=3)
    gp = make_env_map("torch", 1.0)
    sig = run_signature(
        settings,
        type("PRO", (), {}),
        {"beta": 1.0, "shape": (1, 2)},
        gp,
        torch.float64,
        solved=False,
        labels=True,
    )
    assert sig["optimizer_kwargs"] == {"beta": 1.0, "shape": [1, 2]} and sig["labels"] is True
    assert "each_label" not in sig and sig["seed"] == 3
    state = RunState(sig, tmp_path, save=save_model)
    data = state.start(ds, promp, resume=False)
    assert data is not ds and len(data) == len(ds)
    state.fit(gp, data)
    state.rows = [{"step": 0, "dataset_size": len(data)}, {"step": 1, "added": 0, "success": 2}]
    state.step, state.tried = 1, [0, 1]
    state.checkpoint(data, gp)
    assert "loop" not in ds.metadata  # the state went into the copy's metadata only
    with pytest.raises(FileExistsError, match="resume=True"):
        RunState(sig, tmp_path, save=save_model).start(ds, promp, resume=False)
    again = RunState(sig, tmp_path, save=save_model)
    loaded = again.start(ds, promp, resume=True)
    assert isinstance(loaded, TrajectoryDataset) and torch.equal(loaded.mean, data.mean)
    assert (again.step, again.tried, again.resumed_from, again.successes) == (1, [0, 1], 1, 2)
    other = RunState({**sig, "seed": 4}, tmp_path, save=save_model)
    with pytest.raises(ValueError, match="other settings.*'seed': \\(3, 4\\)"):
        other.start(ds, promp, resume=True)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
