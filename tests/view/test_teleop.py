"""The teleoperation page's session without a browser: a person pushing only forward is steered
through the moving window by the adaptive guide and not without one; the study's order and files."""

import csv
import json

import pytest
import torch
from teleop_run import make_teleop_run  # tests/view/teleop_run.py (this folder is on sys.path)

from protorch.view.teleop import CSV_COLUMNS, TeleopSession, study_order


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return make_teleop_run(tmp_path_factory.mktemp("teleop"))


def _push_forward(session, condition, steps=400, dt=0.02):
    """Forward at 0.25 m/s up to x = 1.25 m, the hand yielding 8 % per step to the guide."""
    view = session.start(condition)
    wish = session.start_pose.clone()
    for k in range(steps):
        if wish[0] < 1.25:
            wish[0] += 0.25 * dt
        view = session.step(wish, (k + 1) * dt)
        wish = wish + 0.08 * (torch.tensor(view["pose"], dtype=torch.float64) - wish)
        if view["done"]:
            break
    return view


def test_the_adaptive_guide_steers_a_forward_push_through_and_no_guide_does_not(run_dir, tmp_path):
    session = TeleopSession(run_dir, out=tmp_path, time_limit=8.0)
    guided = _push_forward(session, "adaptive")
    assert guided["done"] and guided["success"] and guided["touches"] == 0
    assert max(guided["guide"]["belief"]) > 0.99  # it settled on one way of rolling the beam up
    alone = _push_forward(session, "none", steps=160)  # 0.8 m forward: through the wall's plane
    assert alone["touches"] > 0 and not alone["success"]  # flat into the wall
    rows = list(csv.DictReader((tmp_path / "trials.csv").open()))  # the unfinished trial has no row
    assert tuple(rows[0]) == CSV_COLUMNS
    assert [r["condition"] for r in rows] == ["adaptive"] and rows[0]["success"] == "1"
    assert set(json.loads(rows[0]["wall_schedule"])) == {"env0", "t0", "dur", "delta"}
    raw = list(csv.reader((tmp_path / "poses_000.csv").open()))
    assert len(raw[0]) == 19 and len(raw) - 1 == round(float(rows[0]["time"]) / 0.02)


def test_study_mode_runs_the_conditions_counterbalanced(run_dir, tmp_path):
    assert study_order(["none", "fixed", "adaptive"], 2) == [
        "none",
        "fixed",
        "adaptive",
        "fixed",
        "adaptive",
        "none",
    ]
    session = TeleopSession(run_dir, study=1, conditions=["none", "adaptive"], out=tmp_path)
    assert session.start("adaptive")["condition"] == "none"  # the plan's, not the page's choice
    with pytest.raises(ValueError, match="unknown condition 'sometimes'"):
        TeleopSession(run_dir, conditions=["sometimes"])
    with pytest.raises(ValueError, match="finite"):
        session.step([float("nan")] * 7, 0.1)
