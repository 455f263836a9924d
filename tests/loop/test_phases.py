"""The phases of a loop step on small hand-made inputs: the choice of environments, the costs
asked for, one solution per class, the per-environment flags, the iteration count."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from protorch import ProMP
from protorch.loop import phases
from protorch.loop.phases import (
    Evaluator,
    choose,
    cost_chunks,
    iterations_per_problem,
    one_per_class,
    per_env,
    sample_costs,
)
from protorch.tasks import PointParticleTask

from .test_loop import Reach

F64 = torch.float64


def test_choose_random_takes_untried_in_draw_order_and_nearest_the_closest_first():
    pool = torch.tensor([[0.0, 0.0], [5.0, 5.0], [1.0, 0.0], [1.0, 0.0], [3.0, 0.0]], dtype=F64)
    known = torch.tensor([[1.1, 0.0]], dtype=F64)
    assert choose(pool, [0, 2], known, 2, "random").tolist() == [1, 3]
    assert choose(pool, [], known, 3, "nearest").tolist() == [2, 3, 0]  # ties (2, 3) by draw order
    assert choose(pool, [0, 1, 2, 3], known, 3, "nearest").tolist() == [
        4
    ]  # the last batch is smaller
    assert choose(pool, list(range(5)), known, 2, "random").numel() == 0


def test_one_per_class_keeps_the_cheapest_accepted_solution_of_each_environment_and_label():
    # k = 2 labels' problems for b = 3 environments, label-major
    accept = torch.tensor([True, True, True, True, False, True])
    label = torch.tensor([0, 1, 1, 0, 0, 1])  # env 0: classes 0, 0; env 1: 1, 0; env 2: 1, 1
    cost = torch.tensor([2.0, 1.0, 5.0, 1.0, 0.0, 4.0])
    kept = one_per_class(accept, label, cost, 2)
    assert kept.tolist() == [False, True, False, True, False, True]
    # env 0: the cheaper (problem 3); env 1: both (other classes); env 2: the cheaper (problem 5)
    assert not bool((kept & ~accept).any())  # never accepts what was refused


def test_per_env_takes_the_flag_of_each_environments_lowest_cost_problem():
    flag = torch.tensor([True, False, False, True])  # k = 2, b = 2
    cost = torch.tensor([1.0, 3.0, 2.0, 0.5])
    assert per_env(flag, cost, 2).tolist() == [True, True]
    assert per_env(flag, torch.tensor([3.0, 0.0, 1.0, 1.0]), 2).tolist() == [False, False]


def test_iterations_count_until_each_problem_stopped_moving():
    mean0 = torch.zeros(3, 2)
    hist = torch.zeros(4, 3, 2)
    hist[:, 0] = torch.arange(1.0, 5.0)[:, None]  # moves every iteration: 4
    hist[:, 1] = 1.0  # moves at iteration 1, then stays: 1
    res = SimpleNamespace(history={"mean": hist})  # problem 2 never moves: 0
    assert iterations_per_problem(res, mean0).tolist() == [4, 1, 0]
    assert iterations_per_problem(SimpleNamespace(history={}), mean0).tolist() == [0, 0, 0]


class Counting(Reach):
    """Reach that records what it is asked to evaluate."""

    def __init__(self):
        self.calls = []

    def costs(self, traj, env):
        self.calls.append(("all", traj.shape[0]))
        return super().costs(traj, env)

    def objective_cost(self, traj, env, o):
        self.calls.append((o, traj.shape[0]))
        return super().costs(traj, env)[..., o]


def test_sample_costs_evaluate_the_active_problems_and_the_asked_objective_only():
    task, promp = Counting(), ProMP(2, num_basis=4, num_steps=20)
    ev = Evaluator.build(task, promp, eval_dtype=None, sample_steps=None, labeler=None, dtype=F64)
    w = torch.randn(3, 5, promp.num_weights, dtype=F64)  # (b, S, N)
    env = task.sample_envs(3, torch.Generator().manual_seed(0))  # (b, E)
    opt = SimpleNamespace(
        active=torch.tensor([True, False, True]), asked_objective=None, num_objectives=2
    )
    c = sample_costs(ev, opt, w, env)
    assert task.calls == [("all", 2)] and c.shape == (3, 5, 2)
    assert bool((c[1] == 0).all())
    want = Reach().costs(promp.trajectory(w[[0, 2]]), env[[0, 2]][:, None])
    torch.testing.assert_close(c[[0, 2]], want)
    task.calls.clear()
    opt.asked_objective = 1
    c1 = sample_costs(ev, opt, w, env)
    assert task.calls == [(1, 2)] and bool((c1[..., 0] == 0).all())
    torch.testing.assert_close(c1[[0, 2], :, 1], want[..., 1])
    task.calls.clear()
    opt.active = torch.zeros(3, dtype=torch.bool)
    assert not bool(sample_costs(ev, opt, w, env).any()) and task.calls == []


def test_costs_in_chunks_and_on_an_objectives_own_steps_are_the_numbers_of_one_call(monkeypatch):
    """Chunks that keep torch's vectorised loops full, and a trajectory of the two end points
    (a padded basis), change no bit of the point particle's costs."""
    task, promp = PointParticleTask(objectives="clearance"), ProMP(2, num_basis=10, num_steps=100)
    ev = Evaluator.build(
        task, promp, eval_dtype=torch.float32, sample_steps=None, labeler=None, dtype=F64
    )
    g = torch.Generator().manual_seed(1)
    env = task.sample_envs(7, g)  # (b, E)
    start, goal = (
        env[:, 0:2],
        env[:, 4:6],
    )  # a line from start to goal through the hole's centre, and noise
    via = torch.stack([start, env[:, 2:4], goal], 1)  # (b, 3, 2)
    mu = promp.weights(
        torch.nn.functional.interpolate(
            via.transpose(1, 2), size=100, mode="linear", align_corners=True
        ).transpose(1, 2)
    )  # (b, N)
    w = (
        mu[:, None] + 0.3 * torch.randn(7, 16, mu.shape[-1], generator=g, dtype=F64)
    ).float()  # (b, S, N)
    env_e = env.float()
    opt = SimpleNamespace(
        active=torch.tensor([True, True, False, True, True, True, True]),
        asked_objective=None,
        num_objectives=3,
    )
    whole = {
        o: sample_costs(ev, SimpleNamespace(**{**vars(opt), "asked_objective": o}), w, env_e)
        for o in (None, 0, 1, 2)
    }
    monkeypatch.setattr(phases, "CHUNK_FLOATS", 16 * 100 * 2 * 2)  # 2 problems per call
    for o, want in whole.items():
        got = sample_costs(ev, SimpleNamespace(**{**vars(opt), "asked_objective": o}), w, env_e)
        assert torch.equal(got, want)
    full = ev.promp_sample.trajectory(w[opt.active])  # (a, S, T, 2)
    assert torch.equal(
        whole[0][opt.active][..., 0], task.costs(full, env_e[opt.active][:, None])[..., 0]
    )
    assert torch.equal(
        ev.sample_trajectory(w, (0, -1)), ev.promp_sample.trajectory(w)[..., [0, -1], :]
    )


def test_cost_chunks_fill_the_vectorised_loops():
    assert (
        cost_chunks(100, 100, 100, 2) == 26
    )  # 2^19 numbers, an even count (S T = 10^4 = 16 mod 32)
    assert cost_chunks(3, 100, 100, 2) == 3 and cost_chunks(100, 7, 3, 2) == 100
    for problems, samples, steps, n in (
        (100, 101, 99, 20),
        (1000, 20, 50, 70),
        (64, 100, 2, 7),
        (500, 100, 20, 70),
    ):
        c = cost_chunks(problems, samples, steps, 7, n)
        assert c == problems or ((c * samples * steps) % 32 == 0 and (c * samples * n) % 32 == 0)


def test_evaluator_samples_the_same_basis_on_a_coarser_grid():
    promp = ProMP(2, num_basis=4, num_steps=21)
    ev = Evaluator.build(
        Reach(), promp, eval_dtype=torch.float32, sample_steps=11, labeler=None, dtype=F64
    )
    assert ev.eval_dtype == torch.float32 and ev.promp.basis.dtype == torch.float32
    assert promp.basis.dtype == F64  # the caller's ProMP is left alone
    mu = torch.randn(1, promp.num_weights, dtype=torch.float32)
    fine, coarse = ev.promp.trajectory(mu), ev.promp_sample.trajectory(mu)  # (1, 21, 2), (1, 11, 2)
    assert coarse.shape == (1, 11, 2)
    torch.testing.assert_close(coarse, fine[:, ::2])  # every other phase of the 21-step grid
