"""Sec. IV-A (beam through a window): the two-stage optimisation at a tiny budget, the paper's
claims at the paper's budget, and settings refused before any work."""

from __future__ import annotations

import pytest
import torch

from protorch.experiments import run_experiment
from protorch.experiments.beam_window import optimize_pose_promp, run
from protorch.primitives.pose import PoseProMP
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator

F64 = torch.float64
TINY_PRO = dict(
    beta=200.0,
    num_samples=40,
    max_iter=12,
    tol=0.0,
    relevance_samples=40,
    relevance_var=1e-5,
    noise_floor=3.0,
)


def _cfg(**optimizer):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from protorch.app.main import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        cfg = compose(config_name="config", overrides=["experiment=beam_window", "plot=false"])
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    plain["optimizer"].update(optimizer)
    return OmegaConf.to_container(
        OmegaConf.create(plain), resolve=True
    )  # baseline_optimizer: ${optimizer.*}


def test_config_holds_the_papers_settings():
    cfg = _cfg()
    opt, task = cfg["optimizer"], cfg["task"]
    assert (opt["beta"], opt["max_iter"], opt["num_samples"]) == (200.0, 150, 200)
    assert (task["length_weight"], task["jerk_weight"]) == (0.1, 1e5)
    assert cfg["settings"]["num_demos"] == 10 and cfg["settings"]["teleop"]["trials"] == 100
    assert cfg["settings"]["eval_samples"] == 1000


@pytest.mark.slow
def test_two_stage_optimisation_at_a_tiny_budget():
    task = BeamWindowTask()
    demos = SimulatedOperator().trials(task, 10, torch.Generator().manual_seed(3))
    model = PoseProMP(10, 100).fit(demos, reference=torch.tensor(task.start_quaternion, dtype=F64))
    before = model.copy()
    stages = optimize_pose_promp(task, model, optimizer=TINY_PRO, seed=0)
    pos, rot = stages["position"]["result"], stages["orientation"]["result"]
    assert pos.iterations == rot.iterations == 12
    # stage 1 moved the position ProMP only, stage 2 the orientation ProMP only
    torch.testing.assert_close(model.position.mean, pos.mean)
    torch.testing.assert_close(model.position.var, pos.var)
    torch.testing.assert_close(model.orientation.mean, rot.mean)
    assert not torch.equal(model.position.mean, before.position.mean)
    assert not torch.equal(model.orientation.mean, before.orientation.mean)
    # the orientation's window via points sit where the optimised position mean passes them
    torch.testing.assert_close(
        stages["phases"], task.window_phases(model.position.mean_trajectory())
    )
    assert 0 < float(stages["phases"][1]) < float(stages["phases"][2]) < 1
    # both problems improved their mean's costs (4 via points + 0.1 len + 1e5 jerk each)
    z = stages["phases"]
    pos_before = task.position_costs(before.position.mean_trajectory()).sum()
    pos_after = task.position_costs(model.position.mean_trajectory()).sum()
    rot_before = task.orientation_costs(before.orientation.mean_trajectory(), z).sum()
    rot_after = task.orientation_costs(model.orientation.mean_trajectory(), z).sum()
    assert pos_after < pos_before and rot_after < 0.8 * rot_before, (
        pos_before,
        pos_after,
        rot_before,
        rot_after,
    )
    with pytest.raises(ValueError, match="beta must be > 0"):
        optimize_pose_promp(task, model, optimizer={**TINY_PRO, "beta": 0.0})


@pytest.mark.slow
def test_the_papers_claims_at_a_reduced_budget(tmp_path):
    """80 iterations x 100 samples per stage (the paper: 150 x 200, measured in the README), 1000
    samples, 100 + 100 simulated trials: about 4 s on one free core."""
    cfg = _cfg(max_iter=80, num_samples=100, relevance_samples=100)
    cfg["settings"]["num_threads"] = 1  # robust to a loaded machine (see run's docstring)
    threads = torch.get_num_threads()
    m = run_experiment(cfg, tmp_path)
    assert torch.get_num_threads() == threads  # restored
    assert m["demos"]["collision_free_rate"] <= 0.5  # most demonstrations hit the wall
    assert (
        m["demos"]["promp_samples_collision_free_rate"] < 0.2
    )  # and so do the demonstrations' ProMP's samples
    assert m["optimized"]["mean_collision_free"] and m["optimized"]["mean_success"]
    assert m["optimized"]["samples_collision_free_rate"] >= 0.9
    assert max(m["optimized"]["via_errors"]["position_m"]) < 0.005  # mm-level via points
    assert max(m["optimized"]["via_errors"]["angle_deg"]) < 3.0
    t = m["teleop"]
    assert t["assisted_success_rate"] >= 0.9
    assert t["assisted_success_rate"] >= 3 * t["unassisted_success_rate"]
    assert t["paired"]["broken_by_guidance"] == 0
    assert (
        t["assisted_by_demos_promp_success_rate"] < 0.6
    )  # guidance from the unoptimised ProMP does not do it
    assert (tmp_path / "metrics.json").is_file()


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(optimizer={"beta": -1.0}), "beta must be > 0"),
        (
            dict(task={"start_quaternion": [1.0, 0.0, 0.0, 0.3]}),
            "start_quaternion must be a unit quaternion",
        ),
        (
            dict(task={"wall_quaternion": [1.0, 0.0, float("nan"), 0.0]}),
            "wall_quaternion contains NaN",
        ),
        (dict(teleop={"trials": 0}), "teleop.trials must be an int >= 1"),
        (dict(teleop={"speed": 1.0}), "unknown teleop setting"),
        (dict(guidance={"position_max": -5.0}), "position_max must be finite and >= 0"),
        (dict(operator={"tilt_std": -1.0}), "tilt_std must be finite and >= 0"),
        (dict(promp={"num_basis": 1}), "num_basis >= 2"),
        (dict(eval_dtype="float16"), "dtype must be one of"),
        (dict(num_threads=0), "num_threads must be an int >= 1"),
    ],
)
def test_bad_settings_are_refused_before_any_work(tmp_path, change, message):
    optimizer = {**TINY_PRO, **change.pop("optimizer", {})}
    with pytest.raises(ValueError, match=message):
        run(tmp_path, optimizer=optimizer, plot=False, **change)
    assert not any(tmp_path.iterdir())  # nothing written
