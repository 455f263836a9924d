"""The refill loop (``refill=True``): B slots in flight, each refilled as soon as its problems stop;
every environment tried once, solutions added as they come, rows every B finished environments,
checkpoints that a crashed run resumes from without losing finished work."""

from __future__ import annotations

import pytest
import torch

from protorch import PRO, RWR
from protorch.data.checkpoint import checkpoint_path
from protorch.data.dataset import TrajectoryDataset
from protorch.loop import can_refill
from protorch.loop.refill import problem_budget
from protorch.optim import EPRO

from .test_loop import KW, Crash, crash_at_2, learned, loop, setup


@pytest.mark.parametrize("batch_size", [1, 3])
def test_every_environment_once_and_rows_every_batch(batch_size):
    task, promp, ds = setup()
    res = loop(
        task,
        promp,
        ds,
        num_envs=11,
        batch_size=batch_size,
        add_only="all",
        refill=True,
        eval_envs=task.sample_envs(5),
    )
    assert sorted(res.tried) == list(range(11))
    rows = res.metrics[1:]
    assert sum(r["batch"] for r in rows) == 11 and [r["envs_done"] for r in rows][-1] == 11
    assert all(
        r["batch"] >= batch_size for r in rows[:-1]
    )  # a row once B more environments finished
    assert [r["step"] for r in res.metrics] == list(range(len(rows) + 1))
    # add_only="all": every solution joins, in the order the environments finished
    assert len(res.dataset) == 4 + 11 and int(learned(res.dataset).sum()) == 11
    torch.testing.assert_close(res.dataset.env[4:], res.pool[res.tried])
    assert all(sum(r["adds"]) == r["added"] for r in rows)
    assert res.env_map.num_points == 15
    for r in rows:  # each problem within its own iteration budget, its rollouts counted
        assert 1 <= r["iterations_max"] <= KW["max_iter"]
        assert 0 < r["rollouts"] <= r["batch"] * KW["max_iter"] * 3 * 20
    again = loop(
        task, promp, setup()[2], num_envs=11, batch_size=batch_size, add_only="all", refill=True
    )
    assert again.tried == res.tried and torch.equal(again.dataset.mean, res.dataset.mean)


def test_a_slot_is_refilled_while_slower_problems_run():
    """With a budget of 4 iterations for some problems and of 15 for none, the step loop waits
    for a step's slowest problem; refill finishes environments one by one, so the environments
    finish in an order that is not the pool's (a slot freed early takes the next one)."""
    task, promp, ds = setup()
    res = loop(task, promp, ds, num_envs=12, batch_size=4, add_only="all", refill=True)
    assert res.tried != sorted(res.tried)  # finish order: not the draw order


def test_a_group_of_finished_environments_is_added_and_refilled_together():
    task, promp, ds = setup()
    one = loop(task, promp, ds, num_envs=12, batch_size=4, add_only="all", refill=True)
    grouped = loop(
        task,
        promp,
        setup()[2],
        num_envs=12,
        batch_size=4,
        add_only="all",
        refill=True,
        refill_group=3,
    )
    assert sorted(grouped.tried) == list(range(12)) and len(grouped.dataset) == 4 + 12
    adds = [n for r in grouped.metrics[1:] for n in r["adds"]]
    assert sum(adds) == 12 and len(adds) < len([n for r in one.metrics[1:] for n in r["adds"]])
    assert all(
        n >= 3 for n in adds[:-2]
    )  # the last ones, with fewer than 3 busy slots, come one by one
    assert all(
        r["iterations_max"] <= KW["max_iter"] for r in grouped.metrics[1:]
    )  # waiting is not iterating
    # out of iterations, not converged: so flagged, though frozen in the optimiser while waiting
    conv = loop(
        task,
        promp,
        setup()[2],
        num_envs=12,
        batch_size=4,
        add_only="converged",
        refill=True,
        refill_group=3,
        optimizer_kwargs={**KW, "max_iter": 4},
    )
    assert int(learned(conv.dataset).sum()) == sum(r["converged"] for r in conv.metrics[1:]) < 12


def test_solved_and_converged_flags_as_in_the_step_loop():
    task, promp, ds = setup()
    res = loop(
        task,
        promp,
        ds,
        num_envs=8,
        batch_size=3,
        add_only="converged",
        solved=task.success,
        refill=True,
    )
    new = learned(res.dataset)
    assert bool(res.dataset.converged[new].all())
    assert int(new.sum()) == sum(r["converged"] for r in res.metrics[1:])
    assert bool(task.success(promp.trajectory(res.dataset.mean[new]), res.dataset.env[new]).all())


def test_each_label_keeps_both_problems_of_an_environment_together():
    task, promp, ds = setup()

    def labeler(traj, env):
        mid = traj[:, traj.shape[1] // 2]
        return (mid[:, 1] > mid[:, 0]).long()

    ds.label[:] = torch.tensor([0, 1, 0, 1])
    res = loop(
        task,
        promp,
        ds,
        num_envs=8,
        batch_size=3,
        add_only="all",
        labeler=labeler,
        each_label=True,
        refill=True,
    )
    new = learned(res.dataset)
    pairs = {
        (tuple(e.tolist()), int(l)) for e, l in zip(res.dataset.env[new], res.dataset.label[new])
    }
    assert len(pairs) == int(new.sum()) and 8 <= int(new.sum()) <= 16
    assert sorted(res.tried) == list(range(8))
    assert all(
        r["converged"] <= 2 * r["batch"] and r["success"] <= r["batch"] for r in res.metrics[1:]
    )


def test_optimisers_that_cannot_restart_are_refused():
    task, promp, ds = setup()
    assert can_refill(PRO, KW) and can_refill(RWR, {"beta": 1.0})
    assert not can_refill(PRO, {**KW, "relevance_every": 0}) and not can_refill(EPRO, {})
    with pytest.raises(ValueError, match="refill=True needs an optimiser"):
        loop(
            task,
            promp,
            ds,
            refill=True,
            optimizer=EPRO,
            optimizer_kwargs={"num_samples": 20, "max_iter": 5},
        )
    assert problem_budget(PRO, KW) == 15 and problem_budget(PRO, {"beta": 1.0}) == 200


def test_restart_gives_a_row_a_new_problem_and_leaves_the_others():
    """A restarted row starts afresh (mean, variance, flags, age, rollouts); its convergence
    window holds its own iterations only, so it cannot converge before ``window`` of them."""
    mean, var = torch.zeros(3, 4, dtype=torch.float64), torch.full((3, 4), 0.1, dtype=torch.float64)
    opt = RWR(mean, var, beta=1.0, num_samples=8, tol=1e-9, window=3, seed=0, max_iter=100)
    opt.history_limit = 3
    cost = lambda w: torch.zeros(*w.shape[:2], 1, dtype=w.dtype)  # noqa: E731 constant: converges at window
    for _ in range(3):
        opt.tell(cost(opt.ask()))
    assert bool(opt.converged.all()) and opt.age.tolist() == [3, 3, 3]
    assert all(len(v) <= 3 for v in opt.history.values())
    other = opt.mean[1:].clone()
    opt.restart(
        torch.tensor([0]),
        torch.ones(1, 4, dtype=torch.float64),
        torch.full((1, 4), 0.5, dtype=torch.float64),
    )
    assert opt.converged.tolist() == [False, True, True] and opt.age.tolist() == [0, 3, 3]
    assert opt.rollouts[0] == 0 and torch.equal(
        opt.var[0], torch.full((4,), 0.5, dtype=torch.float64)
    )
    opt.tell(cost(opt.ask()))
    assert not bool(opt.converged[0])  # the old problem's settled window does not count
    assert torch.equal(opt.mean[1:], other)  # converged rows do not move
    for _ in range(2):
        opt.tell(cost(opt.ask()))
    assert bool(opt.converged[0]) and opt.age[0] == 3
    with pytest.raises(ValueError, match="restart needs"):
        opt.restart(torch.tensor([0]), torch.ones(2, 4), torch.ones(2, 4))


@pytest.mark.slow
def test_resume_after_a_crash_keeps_every_finished_environment(tmp_path):
    task, promp, ds = setup()
    run = tmp_path / "run"
    with pytest.raises(Crash):
        loop(
            task, promp, ds, num_envs=12, batch_size=3, run_dir=run, on_step=crash_at_2, refill=True
        )
    killed = TrajectoryDataset.load(checkpoint_path(run))
    state = killed.metadata["loop"]
    assert state["step"] == 2 and len(state["tried"]) >= 6
    with pytest.raises(ValueError, match="other settings.*'refill'"):
        loop(task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, resume=True)
    res = loop(
        task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, resume=True, refill=True
    )
    assert res.resumed_from == 2 and sorted(res.tried) == list(range(12))
    assert res.tried[: len(state["tried"])] == state["tried"]
    m = len(killed)  # every entry of the killed run's data set is still there, in the same place
    torch.testing.assert_close(res.dataset.env[:m], killed.env)
    assert torch.equal(res.dataset.mean[:m], killed.mean)
    # the map was rebuilt by replaying the same adds: a second resume of the finished run agrees
    done = loop(
        task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, resume=True, refill=True
    )
    assert len(done.dataset) == len(res.dataset)
    q = task.sample_envs(4, torch.Generator().manual_seed(5))
    assert torch.equal(done.env_map.predict_mean(q), res.env_map.predict_mean(q))
