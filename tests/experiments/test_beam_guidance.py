"""The guidance comparison of the beam experiment: the free-phase mask and force, a wider
distribution feeling softer, the settings' errors, and a tiny-budget comparison."""

import pytest
import torch

from protorch.experiments.beam_guidance import (
    compare_guidance,
    compare_settings,
    free_force,
    free_phase_mask,
    optimize_with,
)
from protorch.primitives.pose import PoseProMP
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator

F64 = torch.float64


def test_free_phase_mask_excludes_the_via_neighbourhoods():
    idx = torch.arange(11)[None]  # (1, 11) phases 0, 0.1, ..., 1 on an 11-step grid
    vias = torch.tensor([0.0, 0.5, 1.0], dtype=F64)
    mask = free_phase_mask(idx, 11, vias, 0.15)
    assert mask[0].tolist() == [
        False,
        False,
        True,
        True,
        False,
        False,
        False,
        True,
        True,
        False,
        False,
    ]
    with pytest.raises(ValueError, match="margin"):
        free_phase_mask(idx, 11, vias, 0.5)


def test_free_force_is_the_mean_position_force_magnitude():
    force = torch.zeros(2, 3, 7, dtype=F64)
    force[0, 0, :3] = torch.tensor([3.0, 4.0, 0.0])  # |F| = 5
    force[1, 2, :3] = torch.tensor([0.0, 0.0, 2.0])  # |F| = 2
    force[..., 3:] = 100.0  # the quaternion part is not a force in N: ignored
    mask = torch.tensor([[True, False, False], [True, False, True]])
    assert free_force(force, mask) == pytest.approx((5 + 0 + 2) / 3)
    with pytest.raises(ValueError, match="no step"):
        free_force(force, torch.zeros(2, 3, dtype=torch.bool))


@pytest.mark.parametrize(
    "cfg, match",
    [
        ({"budget": 1}, "budget"),
        ({"margin": 0.6}, "margin"),
        ({"enabled": "yes"}, "enabled"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_settings(cfg, match):
    with pytest.raises(ValueError, match=match):
        compare_settings(cfg)


@pytest.fixture(scope="module")
def beam():
    task = BeamWindowTask()
    person = SimulatedOperator()
    demos = person.trials(task, 6, torch.Generator().manual_seed(0))
    model = PoseProMP(num_basis=6, num_steps=80, dtype=F64)
    model.fit(demos, reference=torch.tensor(task.start_quaternion, dtype=F64))
    intended, lengths = person.intentions(task, 8, torch.Generator().manual_seed(1))
    return task, model, intended, lengths


def test_wider_distribution_pushes_less_in_the_free_phases(beam):
    """Same mean, position std x 4: the clipped K ~ 1/std can only fall, so the free force does."""
    task, model, intended, lengths = beam
    wide = model.copy()
    wide.set_distribution(position=(model.position.mean, model.position.var * 16))
    gains = {"position_gain": 30.0, "position_max": 3000.0}
    out = compare_guidance(
        task,
        model,
        model,
        intended,
        lengths,
        guidance=gains,
        hand={},
        beta=200.0,
        budget=2,
        seed=0,
        names=(),
    )
    out_wide = compare_guidance(
        task,
        model,
        wide,
        intended,
        lengths,
        guidance=gains,
        hand={},
        beta=200.0,
        budget=2,
        seed=0,
        names=(),
    )
    assert set(out) == {"PRO"}
    assert out_wide["PRO"]["free_force"] < out["PRO"]["free_force"]
    assert out_wide["PRO"]["free_stiffness"] < out["PRO"]["free_stiffness"]


def test_tiny_budget_comparison_runs_every_peer(beam):
    task, model, intended, lengths = beam
    before = model.position.mean.clone()
    out = compare_guidance(
        task, model, model, intended, lengths, guidance={}, hand={}, beta=200.0, budget=60, seed=0
    )
    assert list(out) == ["PRO", "EPRO", "RWR", "CEM", "CMA-ES"]
    for r in out.values():
        assert 0 <= r["assisted_success_rate"] <= 1 and r["free_force"] >= 0
    assert torch.equal(model.position.mean, before)  # the demonstrations' ProMP is not changed
    changed = optimize_with("CEM", task, model, beta=200.0, budget=200, seed=0, num_samples=20)
    assert not torch.equal(changed.position.mean, before)
    with pytest.raises(ValueError, match="unknown optimiser"):
        optimize_with("SGD", task, model, beta=200.0, budget=200, seed=0)


def test_pro_stage_rollouts_counts_probes_and_objective_batches():
    from protorch.experiments.beam_guidance import pro_stage_rollouts

    assert (
        pro_stage_rollouts({"max_iter": 150, "num_samples": 200, "pro": {"relevance_samples": 200}})
        == 150_000
    )
    assert (
        pro_stage_rollouts({"max_iter": 3, "num_samples": 20, "pro": {"relevance_samples": 20}})
        == 300
    )


@pytest.mark.slow
def test_experiment_metrics_hold_every_optimiser(tmp_path):
    """The experiment's hook at a tiny budget: new keys only, PRO's guidance as the teleop's."""
    from protorch.experiments.beam_window import run

    opt = dict(beta=200.0, num_samples=20, max_iter=3, tol=0.0, pro=dict(relevance_samples=20))
    m = run(
        tmp_path,
        optimizer=opt,
        plot=True,
        num_demos=4,
        eval_samples=20,
        teleop={"trials": 5},
        promp={"num_steps": 60},
    )
    assert list(m["guidance"]) == ["PRO", "EPRO", "RWR", "CEM", "CMA-ES"]
    assert m["guidance"]["PRO"]["assisted_success_rate"] == m["teleop"]["assisted_success_rate"]
    assert (tmp_path / "guidance.png").is_file()
    off = run(
        tmp_path / "off",
        optimizer=opt,
        plot=False,
        num_demos=4,
        eval_samples=20,
        teleop={"trials": 5},
        promp={"num_steps": 60},
        guidance_compare={"enabled": False},
    )
    assert "guidance" not in off

    def timeless(d):
        return {
            k: timeless(v) if isinstance(v, dict) else v
            for k, v in d.items()
            if k not in ("seconds", "guidance")
        }

    assert timeless(off) == timeless(m)  # the comparison only adds keys
