"""benchmarks/studies/peers.py at a tiny budget: its irrelevant weights really are irrelevant, PRO
keeps
their std while the peers collapse it, and the table has a row per (task, optimiser)."""

from __future__ import annotations

import pytest
import torch

from . import benchmark_module


@pytest.fixture(scope="module")
def peers():
    with benchmark_module("studies/peers.py", "peers_bench") as mod:
        yield mod


def test_nuisance_weights_change_no_cost(peers):
    problems = peers.window_problems(1) + peers.point_particle_problems(1)
    for p in problems:
        assert p.mean.shape[0] == p.n_task + peers.NUISANCE
        peers.check_nuisance(p)  # raises if a cost moves
        assert not p.success(p.mean)  # every start needs improving
    bad = problems[0]
    bad.costs = lambda w, f=bad.costs: (
        f(w) + w[..., -1:].abs()
    )  # a cost that reads a nuisance weight
    with pytest.raises(AssertionError, match="not irrelevant"):
        peers.check_nuisance(bad)


@pytest.mark.slow
def test_pro_keeps_the_std_the_peers_collapse(peers, one_thread):
    (p,) = peers.window_problems(1)
    budget = 3000
    results = {name: [peers.run_one(name, p, budget)] for name in ("PRO", "RWR", "CEM", "CMA-ES")}
    kept = {name: r[0]["std_kept"] for name, r in results.items()}
    # at this budget (seeded, so exact): PRO 1.0, RWR 0.63, CEM 0.05, CMA-ES 0.07
    assert (
        kept["PRO"] > 0.99 and kept["RWR"] < 0.8 and kept["CEM"] < 0.25 and kept["CMA-ES"] < 0.25
    ), kept
    assert all(r[0]["first"] is not None and r[0]["rollouts"] <= budget for r in results.values())
    text = peers.table(
        {("window", k): v for k, v in results.items()},
        1,
        budget,
        "python benchmarks/studies/peers.py",
    )
    rows = [line for line in text.splitlines() if line.startswith("| window")]
    assert [r.split(" | ")[1] for r in rows] == ["PRO", "RWR", "CEM", "CMA-ES"]


@pytest.mark.slow
def test_new_tasks_at_a_tiny_budget(peers, one_thread, tmp_path):
    """Beam stages and arm problems: irrelevant weights really are, every start needs improving,
    EPRO keeps the irrelevant std, and main() writes peers.md and peers.json with the issue's
    keys."""
    import json

    problems = peers.beam_problems(1, "position") + peers.beam_problems(1, "orientation")
    problems += peers.arm_problems(
        1, priors=60, demo_envs=4, prior_detours="[]"
    )  # the straight priors only
    for p in problems:
        peers.check_nuisance(p)
        assert not p.success(p.mean)
    for p in problems:
        r = peers.run_one(peers.EFFICIENT_PRO, p, 400)
        assert r["rollouts"] <= 400 and min(r["std_ratios"]) == 1.0, (
            p.task,
            r,
        )  # unread: not yet read
    out = tmp_path / "peers.md"
    peers.main(
        [
            "--tasks",
            "window",
            "--repeats",
            "2",
            "--budget",
            "300",
            "--optimizers",
            "EPRO,CEM",
            "--seed",
            "3",
            "--out",
            str(out),
            "--json",
            str(tmp_path / "rows.json"),
        ]
    )
    body = json.loads((tmp_path / "rows.json").read_text())
    assert (
        body["efficient_pro"] == "EPRO"
        and set(body["tasks"]["window"]) == {"EPRO", "CEM"}
        and body["seed"] == 3
    )
    keys = {
        "problems",
        "solved",
        "median_rollouts_to_success",
        "irrelevant_std_kept",
        "final_solved",
        "std_kept_p10",
        "std_kept_min",
        "mean_drift_max",
    }
    for row in body["tasks"]["window"].values():
        assert set(row) == keys | {"full_budget"} and set(row["full_budget"]) == keys
        assert (
            row["problems"] == 2
            and row["std_kept_min"] <= row["std_kept_p10"] <= row["irrelevant_std_kept"]
        )
    assert body["command"].startswith("python benchmarks/studies/peers.py")
    assert "| window | EPRO |" in out.read_text() and "full budget" in out.read_text()


def test_row_metrics_read_every_problem_and_unread_weight(peers):
    """p10, min and drift go over every (problem, unread weight), not over per-problem medians;
    solved counts a first success, final_solved the last mean."""
    runs = [
        {
            "first": 40,
            "final_success": False,
            "std_kept": 1.0,
            "iterations": 3,
            "std_ratios": [1.0] * 9 + [0.2],
            "drifts": [0.0] * 9 + [2.5],
        },
        {
            "first": None,
            "final_success": False,
            "std_kept": 1.0,
            "iterations": 3,
            "std_ratios": [1.0] * 10,
            "drifts": [0.1] * 10,
        },
        {
            "first": 80,
            "final_success": True,
            "std_kept": 0.5,
            "iterations": 3,
            "std_ratios": [0.5] * 10,
            "drifts": [0.3] * 10,
        },
    ]
    m = peers.row_metrics(runs)
    assert m["solved"] == 2 and m["final_solved"] == 1 and m["median_rollouts_to_success"] == 60
    assert m["irrelevant_std_kept"] == 1.0  # the median of medians hides both the 0.2 and the 0.5s
    assert m["std_kept_min"] == 0.2 and m["std_kept_p10"] == 0.5 and m["mean_drift_max"] == 2.5


def test_seed_sets_draw_new_problems(peers):
    a, b = peers.point_particle_problems(2, 0), peers.point_particle_problems(2, 1)
    assert not torch.equal(a[0].env, b[0].env) and a[0].optimizer_seed != b[0].optimizer_seed
    assert torch.equal(a[1].env, peers.point_particle_problems(2, 0)[1].env)


@pytest.mark.slow
def test_the_arm_objective_changes_the_costs_not_the_problems(peers):
    """--arm-objective: the same environments and starts, the can objective read by the optimisers
    is the volumes' (the default: what the success check reads), the skeleton's or the paper's end
    effector's, the success check is the same."""
    assert peers.parse_args([]).arm_objective == "volume"
    assert peers.parse_args(["--arm-objective", "ee"]).arm_objective == "ee"
    with pytest.raises(SystemExit):
        peers.parse_args(["--arm-objective", "hand"])
    small = {"priors": 60, "demo_envs": 4, "prior_detours": "[]"}  # the straight priors only
    (ee,) = peers.arm_problems(1, 0, can_objective="ee", **small)
    (sk,) = peers.arm_problems(1, 0, can_objective="skeleton", **small)
    assert (
        torch.equal(ee.env, sk.env)
        and torch.equal(ee.mean, sk.mean)
        and torch.equal(ee.var, sk.var)
    )
    assert sk.task_obj.can_objective == "skeleton" and ee.task_obj.can_objective == "ee"
    w = sk.mean + sk.var.sqrt() * torch.randn(
        8, sk.mean.shape[0], generator=torch.Generator().manual_seed(0), dtype=torch.float64
    )  # (8, N)
    c_ee, c_sk = ee.costs(w), sk.costs(w)  # (8, 3)
    assert torch.equal(c_ee[:, [0, 2]], c_sk[:, [0, 2]]) and not torch.equal(c_ee[:, 1], c_sk[:, 1])
    assert [ee.success(x) for x in w] == [sk.success(x) for x in w]


def test_epro_settings_from_the_command_line_reach_the_optimiser(peers):
    args = peers.parse_args(
        ["--optimizers", "EPRO", "--epro", "provisional_step=0.5", "--epro", "ess=0.25"]
    )
    assert args.epro_options == {"provisional_step": 0.5, "ess": 0.25}
    p = peers.window_problems(1)[0]
    try:
        peers.EPRO_OPTIONS.update(args.epro_options)
        opt = peers.make_optimizer(peers.EFFICIENT_PRO, p, seed=0)
        assert opt.provisional_step == 0.5 and opt.ess == 0.25
    finally:
        peers.EPRO_OPTIONS.clear()
    assert (
        peers.make_optimizer(peers.EFFICIENT_PRO, p, seed=0).provisional_step == 0.75
    )  # the default again
    for bad in ("nosuch=1", "provisional_step", "mean=0"):
        with pytest.raises(SystemExit):
            peers.parse_args(["--epro", bad])
