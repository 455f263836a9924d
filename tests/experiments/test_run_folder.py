"""Run folders: status.json tells running / ok / failed; another experiment's folder is refused;
results files are readable by others; stale temporary files of a killed write are removed."""

from __future__ import annotations

import json
import stat

import pytest

from protorch.experiments import EXPERIMENTS, run_experiment
from protorch.experiments.run_folder import check_run_folder

FIG3 = {
    "name": "fig3_toy",
    "seed": 0,
    "plot": False,
    "threads": 1,
    "optimizer": {"beta": 20.0, "max_iter": 5, "num_samples": 20},
    "settings": {"eval_samples": 50},
}


def test_a_finished_run_writes_summary_and_status_readable_by_others(tmp_path):
    metrics = run_experiment(FIG3, tmp_path)
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["status"] == "ok" and status["experiment"] == "fig3_toy"
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["summary"] == status["summary"] == metrics["summary"]
    assert (
        saved["summary"]["headline"]["pro.irrelevant_std_ratio"]["value"]
        == saved["pro"]["irrelevant_std_ratio"]
    )
    for name in ("metrics.json", "status.json"):
        mode = stat.S_IMODE((tmp_path / name).stat().st_mode)
        assert mode & 0o044 == 0o044, oct(mode)  # group and others may read (umask 022 -> 0644)


def test_a_failed_run_says_so_in_its_folder(tmp_path, monkeypatch):
    def boom(out_dir, **kw):
        raise RuntimeError("disk on fire")

    monkeypatch.setitem(EXPERIMENTS, "fig3_toy", boom)
    with pytest.raises(RuntimeError):
        run_experiment(FIG3, tmp_path)
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["status"] == "failed" and "RuntimeError: disk on fire" in status["error"]
    assert "disk on fire" in status["traceback"] and status["summary"]["status"] == "failed"
    assert not (tmp_path / "metrics.json").exists()


def test_another_experiments_folder_is_refused_before_any_work(tmp_path):
    run_experiment(FIG3, tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(ValueError, match="holds results of experiment 'fig3_toy'"):
        run_experiment({**FIG3, "name": "fig4_window", "settings": {}}, tmp_path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    run_experiment(FIG3, tmp_path)  # the same experiment may run there again


def test_stale_tmp_files_are_removed_at_the_next_start(tmp_path):
    (tmp_path / ".metrics.json.k1ll3d.tmp").write_text("{half")
    (tmp_path / "keep.tmp").write_text("not ours")
    check_run_folder(tmp_path, "fig3_toy")
    assert not (tmp_path / ".metrics.json.k1ll3d.tmp").exists() and (tmp_path / "keep.tmp").exists()


def test_atomic_writes_honour_the_umask(tmp_path):
    import os

    from protorch.data.files import atomic_write_bytes

    old = os.umask(0o077)
    try:
        private = atomic_write_bytes(tmp_path / "private.bin", b"x")
    finally:
        os.umask(old)
    os.umask(0o022)
    try:
        shared = atomic_write_bytes(tmp_path / "shared.bin", b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    assert stat.S_IMODE(shared.stat().st_mode) == 0o644
