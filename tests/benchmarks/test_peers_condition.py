"""benchmarks/studies/peers_condition.py at a tiny budget: exact conditioning puts the mean on the
moved
goal, the arm's goal configuration reaches it, and main() writes the counts per change."""

from __future__ import annotations

import json

import pytest
import torch

from . import benchmark_module


@pytest.fixture(scope="module")
def cond():
    def load(mod):
        mod.peers = mod.load_peers()  # peers.py sets OMP_NUM_THREADS & co. for itself

    with benchmark_module(
        "studies/peers_condition.py", "peers_condition_bench", load, also=("peers_bench",)
    ) as mod:
        yield mod


def test_exact_conditioning_meets_the_moved_goal(cond):
    (p,) = cond.peers.point_particle_problems(1, 5)
    g = torch.Generator().manual_seed(0)
    changes = cond.particle_changes(p, p.promp.trajectory(p.mean[: p.n_task]), g)
    assert [c[0] for c in changes] == ["goal"] * cond.DRAWS + ["hole"] * 2
    model = p.promp.set_distribution(p.mean[: p.n_task].clone(), var=p.var[: p.n_task].clone())
    for kind, env, phase, y in changes:
        traj = model.condition(phase, y).mean_trajectory()  # (T, 2)
        at = traj[round(phase * (traj.shape[0] - 1))]
        assert (at - y).norm() < 1e-6, kind
        if (
            kind == "goal"
        ):  # the new goal is the via point, at most 1 from the old one (clipped to the goal range)
            assert torch.equal(env[4:6], y) and 0 < (env[4:6] - p.env[4:6]).norm() <= 1 + 1e-9
        else:
            assert torch.equal(env[2:4], y) and abs(env[3] - p.env[3]) > 0


def test_arm_goal_configuration_reaches_the_goal(cond):
    (p,) = cond.peers.arm_problems(1, 0, priors=60, demo_envs=4)
    q = p.promp.trajectory(p.mean[: p.n_task])[-1]  # (7,)
    goal = p.task_obj.goal_point(p.env) + torch.tensor([0.03, -0.04, 0.0], dtype=q.dtype)
    q2 = cond.arm_goal_configuration(p.task_obj, q, goal)
    assert (p.task_obj.kinematics.link_positions(q2[None])[0, -1] - goal).norm() < 1e-5


def test_main_writes_counts(cond, tmp_path):
    before = torch.get_num_threads()
    try:
        cond.main(
            [
                "--repeats",
                "1",
                "--budget",
                "300",
                "--tasks",
                "point_particle",
                "--optimizers",
                "CEM",
                "--json",
                str(tmp_path / "c.json"),
            ]
        )
    finally:
        torch.set_num_threads(before)
    body = json.loads((tmp_path / "c.json").read_text())
    rows = body["tasks"]["point_particle"]
    assert set(rows) == {"start", "CEM"}
    for row in rows.values():
        assert set(row) == {"goal", "hole"}
        assert row["goal"]["cases"] == cond.DRAWS and row["hole"]["cases"] == 2
        assert all(
            0 <= row[k][c] <= row[k]["cases"]
            for k in row
            for c in ("not_conditioned", "exact", "soft")
        )
