"""The arm trained from timestamped recordings (task.demos=FOLDER of *.csv) at a tiny budget: the
cleaning report in the metrics, one environment per measured group, a motionless recording excluded
and an environment demonstrated on both sides (one left, two right) trained with the lone side
pooled."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from protorch.data.recordings import write_recording
from protorch.experiments import run_experiment
from tests.benchmarks import benchmark_module
from tests.experiments.test_arm_reach import cfg

# what the recordings are cleaned for is not under test here: the loop, its map and its test at
# their cheapest (no detour priors, no physics, no baselines)
CHEAP = ["task.prior_detours=[]", "settings.physics.run=never", "settings.baselines=[]"]


@pytest.mark.slow
def test_tiny_arm_run_from_recordings(tmp_path, monkeypatch):
    with benchmark_module("recordings.py", "bench_recordings") as bench:
        # the 2 environments recorded, not the experiment's 20 (their IK demonstrations unused); the
        # first demonstrated once on the left and twice on the right, the second three times on the
        # left
        monkeypatch.setattr(bench, "mixed_demos", partial(bench.mixed_demos, envs=2))
        info = bench.make_recordings(
            tmp_path / "rec", 0, count=6, mixed=True
        )  # at 100 / 500 / 1000 Hz
    assert [i["rate"] for i in info] == [100, 500, 1000] * 2 and [i["label"] for i in info] == [
        0,
        1,
        1,
        0,
        0,
        0,
    ]
    still = np.loadtxt(tmp_path / "rec" / "csv" / "demo00.csv", delimiter=",", skiprows=1)
    still[:, 1:8] = still[0, 1:8]  # the arm never moves
    header = (tmp_path / "rec" / "csv" / "demo00.csv").read_text().splitlines()[0].split(",")
    write_recording(tmp_path / "rec" / "csv" / "demo06.csv", header, still)
    m = run_experiment(cfg(f"task.demos={tmp_path / 'rec' / 'csv'}", *CHEAP), tmp_path / "run")
    rec = m["demos"]["recordings"]
    assert (
        m["demos"]["count"] == 6 and m["demos"]["entries"] == 3 and rec["grouping"]["groups"] == 2
    )
    assert [e["file"] for e in rec["excluded"]] == ["demo06.csv"] and rec["excluded"][0][
        "reason"
    ].startswith("motionless")
    assert rec["sides"]["lone"] == [{"files": ["demo00.csv"], "label": 0, "side": "left"}]
    assert rec["grouping"]["derived"] and 0.005 < rec["grouping"]["tolerance"] < 0.2
    off = run_experiment(
        cfg(
            f"task.demos={tmp_path / 'rec' / 'csv'}",
            *CHEAP,
            "task.recordings.trim=false",
            "task.recordings.align=false",
            "task.recordings.group_tol=0.05",
        ),
        tmp_path / "off",
    )
    rec_off = off["demos"]["recordings"]
    assert rec_off["grouping"]["tolerance"] == 0.05 and rec_off["trimmed_s"]["max"] == 0
    assert all(
        0.3 <= r["trimmed_start_s"] <= 2.5 and 0.3 <= r["trimmed_end_s"] for r in rec["recordings"]
    )
    assert "warp_max" in rec and "warp_max" not in rec_off
