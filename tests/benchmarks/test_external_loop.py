"""benchmarks/studies/external/loop.py's task (box pushing over goal poses) on a stand-in for
fancy_gym's
episodes: the identity ProMP, the shapes the loop hands the task, the cache and the episode count,
and a tiny self-improvement loop through it (fancy_gym itself is never imported)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from . import ROOT, benchmark_module

sys.path.insert(0, str(ROOT / "benchmarks" / "external"))


@pytest.fixture(scope="module")
def loop():
    with benchmark_module("studies/external/loop.py", "external_loop", also=("tasks",)) as mod:
        yield mod


class FakeEpisodes:
    """Episodes of a stand-in: return ``-|w - target(goal)|^2`` (``target`` moves with the goal),
    success below ``thr``; records every batch it ran."""

    def __init__(self, thr: float = 1.0) -> None:
        from tasks import Outcome

        self.outcome, self.thr, self.calls = Outcome, thr, []

    @staticmethod
    def target(goal: np.ndarray) -> np.ndarray:  # (S, 3) -> (S, 35)
        return np.repeat(goal[:, :1] * 2 + goal[:, 2:] * 0.1, 35, axis=1)

    def __call__(self, weights, goals):
        self.calls.append((np.array(weights), np.array(goals)))
        d = ((weights - self.target(goals)) ** 2).sum(1)  # (S,)
        return [self.outcome(-float(v), bool(v < self.thr), float(np.sqrt(v)), 0.0) for v in d]


def test_identity_promp_hands_the_task_its_weights_bit_for_bit(loop):
    promp = loop.identity_promp()
    w = torch.randn(4, 6, 35, dtype=torch.float64)
    traj = promp.trajectory(w)  # (4, 6, 5, 7)
    assert traj.shape == (4, 6, 5, 7)
    assert torch.equal(loop.BoxGoalTask.weights(traj), w)
    with pytest.raises(ValueError, match=r"\(\.\.\., 5, 7\).*got \(4, 10, 7\)"):
        loop.BoxGoalTask.weights(torch.zeros(4, 10, 7))


def test_costs_and_success_in_the_loops_shapes_from_one_episode_each(loop):
    fake = FakeEpisodes(thr=30.0)
    task = loop.BoxGoalTask(fake)
    promp = loop.identity_promp()
    env = task.sample_envs(3, torch.Generator().manual_seed(0))  # (3, 3)
    assert env.min() >= 0 and env.max() <= 1
    w = torch.randn(3, 4, 35, dtype=torch.float64)
    traj = promp.trajectory(w)  # (3, 4, 5, 7)
    costs = task.costs(traj, env[:, None])  # (3, 4, 1)
    assert costs.shape == (3, 4, 1)
    goals = task.pose(env)  # (3, 3)
    expected = ((w.numpy() - fake.target(goals)[:, None]) ** 2).sum(-1)  # (3, 4)
    np.testing.assert_allclose(costs[..., 0].numpy(), expected, rtol=1e-12)
    ok = task.success(traj, env[:, None])  # (3, 4): the cache answers, no new episode
    assert ok.dtype == torch.bool and ok.shape == (3, 4)
    assert torch.equal(ok, torch.as_tensor(expected < 30.0))
    assert task.episodes == 12 and len(fake.calls) == 1
    # the goal poses handed to the episodes span the configured ranges
    lo, hi = task.pose(np.zeros(3)), task.pose(np.ones(3))
    np.testing.assert_allclose(lo, [loop.X_RANGE[0], loop.Y_RANGE[0], loop.YAW_RANGE[0]])
    np.testing.assert_allclose(hi, [loop.X_RANGE[1], loop.Y_RANGE[1], loop.YAW_RANGE[1]])
    # a held-out pose's episodes are counted apart
    task.mark_heldout(env[:1])
    task.costs(promp.trajectory(torch.zeros(1, 35, dtype=torch.float64)), env[:1])
    assert (task.episodes, task.heldout_episodes) == (12, 1)


def test_the_protocol_check_passes(loop):
    from protorch.tasks import check_task_outputs

    task = loop.BoxGoalTask(FakeEpisodes())
    traj = loop.identity_promp().trajectory(torch.randn(2, 35, dtype=torch.float64))  # (2, 5, 7)
    assert (
        check_task_outputs(
            task, traj, task.sample_envs(2, torch.Generator().manual_seed(1)), dtype=torch.float32
        )
        == 1
    )


def test_a_tiny_loop_counts_every_episode_it_ran(loop):
    from protorch.gp import make_env_map
    from protorch.loop import LoopSettings, OptimizerSpec, self_improve
    from protorch.optim import CMAES

    fake = FakeEpisodes(thr=5.0)
    task = loop.BoxGoalTask(fake)
    promp = loop.identity_promp()
    res = self_improve(
        task,
        promp,
        loop.prior_dataset(task, promp, 1.0),
        OptimizerSpec(CMAES, {"num_samples": 6, "max_iter": 3, "tol": 0.0}),
        lambda: make_env_map("torch", 5.0),
        LoopSettings(
            num_envs=2,
            batch_size=1,
            add_only="all",
            choice="nearest",
            min_var=0.04,
            var_floor=0.01,
            refill=False,
            eval_dtype=None,
            threads=1,
        ),
        solved=task.success,
    )
    ran = sum(len(w) for w, _ in fake.calls)
    assert task.episodes == ran == len(task.cache)
    rollouts = sum(r["rollouts"] for r in res.metrics[1:])
    # every sample is an episode; the rest are checks of distinct means (at most one per iteration +
    # the start)
    assert rollouts <= ran <= rollouts + 2 * (3 + 1)
    assert len(res.dataset) == 3  # the prior entry and both poses' solutions (add_only="all")
