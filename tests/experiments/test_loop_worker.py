"""Loop baselines in a worker process (protorch.experiments.loop_worker): the same data sets as
the one-process run, the settings' round trip, a failing worker's error."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

import protorch.experiments.loop_run as skeleton
from protorch.data.checkpoint import checkpoint_path
from protorch.experiments.loop_worker import LoopWorker, decode_settings, encode_settings
from protorch.threads import torch_threads

from .test_loop_run import TINY, Twice

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def on_path():
    sys.path.insert(0, str(ROOT))
    yield
    sys.path.remove(str(ROOT))


def _tensors(folder: Path) -> dict:
    return load_file(checkpoint_path(folder))


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        torch.equal(a[k].nan_to_num(7.0), b[k].nan_to_num(7.0)) for k in a
    )


def test_a_worker_runs_the_loop_baseline_with_the_numbers_of_one_process(
    tmp_path, on_path, monkeypatch
):
    started = []

    class Counted(LoopWorker):
        def __init__(self, *args):
            started.append(args[2])
            super().__init__(*args)

    monkeypatch.setattr(skeleton, "LoopWorker", Counted)
    with torch_threads(1):  # one core: the baseline's loop runs here, after the method's
        one = Twice(**TINY).run(tmp_path / "one", baselines=["again"], plot=False)
    with torch_threads(2):  # two: in a worker beside the method's loop (here at 2 - 1 threads)
        two = Twice(**TINY).run(tmp_path / "two", baselines=["again"], plot=False)
    assert started == ["again"]  # one worker, in the second run only
    for sub in (".", "baselines/again"):
        assert _same(_tensors(tmp_path / "one" / sub), _tensors(tmp_path / "two" / sub))
    timing = ("seconds",)
    assert {k: v for k, v in two["again"]["loop"].items() if k not in timing} == {
        k: v for k, v in one["again"]["loop"].items() if k not in timing
    }
    assert (
        two["again"]["loop"]["resumed_from"] is None
    )  # the worker's fresh loop, not the read-back
    assert two["again"]["test"] == one["again"]["test"] and two["test"] == one["test"]


def test_settings_pass_to_a_worker_and_back():
    settings = {
        "seed": 3,
        "dtype": torch.float32,
        "device": torch.device("cpu"),
        "optimizer": {"name": "pro", "beta": 2.5},
        "task": {"fixed_start": (1.0, 2.0), "demos": "synthetic"},
        "loop": None,
        "flag": True,
    }
    back = decode_settings(encode_settings(settings))
    assert back == {
        **settings,
        "task": {"fixed_start": [1.0, 2.0], "demos": "synthetic"},
    }  # tuples come back as lists
    with pytest.raises(TypeError, match="Tensor"):
        encode_settings({"x": torch.zeros(2)})


def test_a_failing_worker_is_reported_with_its_error(tmp_path, on_path):
    exp = Twice(**TINY)
    worker = LoopWorker(
        exp, {**exp.constructed_with, "gp": {"alpha": -1.0}}, "again", tmp_path / "w", False
    )
    with pytest.raises(
        RuntimeError, match=r"(?s)the again loop's worker process failed \(exit code 1\).*alpha"
    ):
        worker.wait()
    worker.stop()
    assert not checkpoint_path(tmp_path / "w").exists()
