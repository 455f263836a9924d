"""The self-improvement loop on a cheap reaching task: growth, add criteria, environment choice,
batch sizes, atomic checkpoints and resuming after a crash or a SIGKILL."""

from __future__ import annotations

import csv
import dataclasses
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch

import protorch
from protorch import PRO, RWR, ProMP, make_env_map
from protorch.data.checkpoint import checkpoint_path
from protorch.data.dataset import ORIGINS, TrajectoryDataset
from protorch.loop import (
    METRICS_FILE,
    LoopSettings,
    OptimizerSpec,
    Run,
    demonstration_dataset,
    group_by_env,
    self_improve,
)

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]


class Reach:
    """Start at the origin, end at the goal ``env = (gx, gy)`` in ``[0.5, 1]^2``: objectives
    ``||tau(0)||`` and ``||tau(T) - goal||``; success: both within 0.05."""

    name = "reach"
    objective_names = ("start", "goal")
    num_objectives = 2
    env_dim = 2

    def costs(self, traj, env):  # (..., T, 2), (..., 2) -> (..., 2)
        return torch.stack(
            [traj[..., 0, :].norm(dim=-1), (traj[..., -1, :] - env).norm(dim=-1)], -1
        )

    def success(self, traj, env):
        return (self.costs(traj, env) <= 0.05).all(-1)

    def sample_envs(self, n, generator=None, *, dtype=F64, device=None):
        return (0.5 + 0.5 * torch.rand(n, 2, generator=generator, dtype=F64)).to(
            dtype=dtype, device=device
        )


def setup(num_demo_envs: int = 4):
    """A ProMP and a data set of 2 noisy straight-line demonstrations per environment."""
    task, promp = Reach(), ProMP(2, num_basis=4, num_steps=20)
    g = torch.Generator().manual_seed(123)
    envs = task.sample_envs(num_demo_envs, g)  # (M, 2)
    s = torch.linspace(0, 1, 20, dtype=F64)[:, None]  # (20, 1)
    demos, demo_envs = [], []
    for e in envs:
        for _ in range(2):
            demos.append(
                s * (e + 0.05 * torch.randn(2, generator=g, dtype=F64))
                + 0.02 * torch.randn(2, generator=g, dtype=F64)
            )
            demo_envs.append(e)
    ds = demonstration_dataset(
        promp, demos, torch.stack(demo_envs), task_name=task.name, var_floor=1e-4
    )
    return task, promp, ds


KW = dict(
    beta=20.0,
    num_samples=20,
    max_iter=15,
    tol=1e-3,
    window=3,
    relevance_samples=20,
    noise_floor=None,
)


RUN_KEYS = {"run_dir": "dir", "resume": "resume", "progress": "progress", "on_step": "on_step"}
LOOP_DEFAULTS = dict(num_envs=10, batch_size=4, refill=False, eval_dtype=None)


def loop(task, promp, ds, **kw):
    """``self_improve`` with these tests' defaults: ``kw`` names settings, run and optimiser
    fields flat (``run_dir``, ``optimizer_kwargs``, ``num_envs``, ...) and is split into the
    :class:`LoopSettings`, :class:`Run` and :class:`OptimizerSpec` the call takes."""
    cls = kw.pop("optimizer", PRO)
    default_kw = (
        KW
        if cls is PRO
        else {k: KW[k] for k in ("beta", "num_samples", "max_iter", "tol", "window")}
    )
    optimizer = OptimizerSpec(cls, kw.pop("optimizer_kwargs", default_kw))
    env_map = kw.pop("env_map", lambda: make_env_map("torch", 1.0))
    run = Run(**{RUN_KEYS[k]: kw.pop(k) for k in list(kw) if k in RUN_KEYS})
    names = {f.name for f in dataclasses.fields(LoopSettings)}
    settings = LoopSettings(**{**LOOP_DEFAULTS, **{k: kw.pop(k) for k in list(kw) if k in names}})
    return self_improve(task, promp, ds, optimizer, env_map, settings, run, **kw)


class Crash(Exception):
    pass


def crash_at_2(row):
    """An ``on_step`` that crashes the loop after its second step's checkpoint."""
    if row["step"] == 2:
        raise Crash


def learned(ds):
    return ds.origin == ORIGINS.index("learned")


# ----------------------------------------------------------------------------- initial data
def test_demonstration_dataset_one_entry_per_environment():
    task, promp, ds = setup(3)
    assert len(ds) == 3 and ds.task_name == "reach" and ds.origin.tolist() == [0, 0, 0]
    assert bool((ds.var >= 1e-4).all()) and bool(ds.converged.all())
    envs = torch.tensor([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [3.0, 4.0], [1.0, 2.0]])
    assert [g.tolist() for g in group_by_env(envs)] == [[0, 2, 4], [1, 3]]
    demos = [torch.rand(10, 2, dtype=F64) for _ in range(5)]
    ds2 = demonstration_dataset(promp, demos, envs)
    w = promp.weights(demos)
    torch.testing.assert_close(ds2.mean[0], w[[0, 2, 4]].mean(0))
    torch.testing.assert_close(ds2.var[1], w[[1, 3]].var(0, unbiased=False))
    with pytest.raises(ValueError, match="1 demonstration"):
        demonstration_dataset(promp, demos[:3], envs[:3])


# ----------------------------------------------------------------------------- the loop
@pytest.mark.parametrize("batch_size", [1, 4])
def test_data_set_grows_and_every_environment_is_tried_once(batch_size):
    task, promp, ds = setup()
    res = loop(
        task, promp, ds, batch_size=batch_size, add_only="all", eval_envs=task.sample_envs(8)
    )
    steps = -(-10 // batch_size)
    assert len(res.metrics) == steps + 1 and res.metrics[0]["step"] == 0
    assert sorted(res.tried) == list(range(10))  # the pool, each environment once
    assert [r["batch"] for r in res.metrics[1:]] == [
        min(batch_size, 10 - batch_size * i) for i in range(steps)
    ]
    assert len(res.dataset) == 4 + 10 and int(learned(res.dataset).sum()) == 10
    torch.testing.assert_close(res.dataset.env[4:], res.pool[res.tried])
    assert res.env_map.num_points == 14
    assert all(0.0 <= r["eval_success"] <= 1.0 for r in res.metrics)
    assert res.metrics[-1]["success_rate"] == sum(r["success"] for r in res.metrics[1:]) / 10
    # the loop improves on what the GP guessed
    assert sum(r["success"] for r in res.metrics[1:]) >= sum(
        r["initial_success"] for r in res.metrics[1:]
    )
    # rollouts: PRO's samples per active iteration, O = 2 objectives' batches and a relevance batch
    # of 20 each
    for r in res.metrics[1:]:
        per_iteration = (2 + 1) * 20
        assert (
            r["rollouts"] % 20 == 0
            and 0 < r["rollouts"] <= r["batch"] * KW["max_iter"] * per_iteration
        )
    # deterministic in the seed
    again = loop(task, promp, setup()[2], batch_size=batch_size, add_only="all")
    assert again.tried == res.tried and torch.equal(again.dataset.mean, res.dataset.mean)


def test_add_only_converged_or_successful_solutions():
    task, promp, ds = setup()
    res = loop(task, promp, ds, num_envs=12, add_only="success")
    new = learned(res.dataset)
    assert (
        int(new.sum())
        == sum(r["success"] for r in res.metrics[1:])
        == sum(r["added"] for r in res.metrics[1:])
    )
    assert bool(task.success(promp.trajectory(res.dataset.mean[new]), res.dataset.env[new]).all())
    res = loop(
        task,
        promp,
        setup()[2],
        num_envs=12,
        add_only="converged",
        optimizer_kwargs={**KW, "max_iter": 4},
    )
    new = learned(res.dataset)
    assert bool(res.dataset.converged[new].all())
    assert (
        int(new.sum()) == sum(r["converged"] for r in res.metrics[1:]) < 12
    )  # some ran out of iterations


def test_solved_stops_problems_early_and_counts_as_converged():
    task, promp, ds = setup()
    full = loop(task, promp, ds, num_envs=8, add_only="converged")
    early = loop(task, promp, setup()[2], num_envs=8, add_only="converged", solved=task.success)
    it = lambda r: sum(x["iterations_mean"] * x["batch"] for x in r.metrics[1:])  # noqa: E731
    assert it(early) < it(full)
    new = learned(early.dataset)
    assert bool(
        task.success(promp.trajectory(early.dataset.mean[new]), early.dataset.env[new]).all()
    )


def test_nearest_choice_takes_the_closest_untried_environment_first():
    task, promp, ds = setup()
    known0 = ds.env.clone()
    picks = []
    res = loop(
        task,
        promp,
        ds,
        num_envs=6,
        batch_size=1,
        choice="nearest",
        add_only="all",
        on_step=lambda row: picks.append(row["step"]),
    )
    pool = res.pool
    first = int(torch.cdist(pool, known0).amin(1).argmin())
    assert res.tried[0] == first
    # every later pick is the untried environment closest to what was known at that step
    for k in range(1, 6):
        known = torch.cat([known0, pool[res.tried[:k]]])
        untried = [i for i in range(6) if i not in res.tried[:k]]
        d = torch.cdist(pool[untried], known).amin(1)
        assert res.tried[k] == untried[int(d.argmin())]
    random = loop(
        task, promp, setup()[2], num_envs=6, batch_size=1, choice="random", add_only="all"
    )
    assert random.tried == list(range(6))


def test_demonstrations_with_labels_form_one_entry_per_environment_and_label():
    task, promp, _ = setup()
    envs = torch.tensor([[0.6, 0.7]] * 4 + [[0.9, 0.8]] * 2, dtype=F64)
    demos = [torch.rand(12, 2, dtype=F64) for _ in range(6)]
    ds = demonstration_dataset(promp, demos, envs, labels=torch.tensor([0, 1, 0, 1, 1, 1]))
    assert ds.label.tolist() == [0, 1, 1] and torch.equal(ds.env[0], ds.env[1])
    torch.testing.assert_close(
        ds.mean[0], promp.weights(demos)[[0, 2]].mean(0)
    )  # never across labels
    with pytest.raises(ValueError, match="label 1.*1 demonstration"):
        demonstration_dataset(promp, demos[:3], envs[:3], labels=torch.tensor([0, 1, 0]))
    with pytest.raises(ValueError, match="labels must be"):
        demonstration_dataset(promp, demos, envs, labels=torch.zeros(6))


def test_labeler_stores_each_solution_with_its_class(tmp_path):
    task, promp, ds = setup()

    def labeler(traj, env):  # (b, T, 2), (b, 2): which side of the diagonal the path's middle lies
        mid = traj[:, traj.shape[1] // 2]
        return (mid[:, 1] > mid[:, 0]).long()

    res = loop(
        task,
        promp,
        ds,
        num_envs=12,
        add_only="all",
        labeler=labeler,
        run_dir=tmp_path,
        eval_envs=task.sample_envs(6),
    )
    new = learned(res.dataset)
    assert int(new.sum()) == 12
    want = labeler(promp.trajectory(res.dataset.mean[new]), res.dataset.env[new])
    assert torch.equal(res.dataset.label[new], want)
    assert torch.equal(res.env_map.labels, res.dataset.label)  # the map keeps the classes apart
    assert all(r["eval_success"] is not None for r in res.metrics)  # label-aware held-out check
    # a checkpoint written with labels cannot be resumed without them (and the reverse)
    with pytest.raises(ValueError, match="labels"):
        loop(task, promp, setup()[2], num_envs=12, add_only="all", run_dir=tmp_path, resume=True)


def test_each_label_optimises_every_class_and_keeps_one_solution_per_class(tmp_path):
    task, promp, ds = setup()

    def labeler(traj, env):
        mid = traj[:, traj.shape[1] // 2]
        return (mid[:, 1] > mid[:, 0]).long()

    ds.label[:] = torch.tensor([0, 1, 0, 1])  # both classes known from the start
    res = loop(
        task,
        promp,
        ds,
        num_envs=8,
        add_only="all",
        labeler=labeler,
        each_label=True,
        sample_steps=7,
    )
    new = learned(res.dataset)
    # two problems per environment, at most one stored solution per (environment, final class)
    pairs = {
        (tuple(e.tolist()), int(l)) for e, l in zip(res.dataset.env[new], res.dataset.label[new])
    }
    assert len(pairs) == int(new.sum()) and 8 <= int(new.sum()) <= 16
    assert all(
        r["converged"] <= 2 * r["batch"] and r["success"] <= r["batch"] for r in res.metrics[1:]
    )
    with pytest.raises(ValueError, match="needs a labeler"):
        loop(task, promp, setup()[2], each_label=True)
    with pytest.raises(ValueError, match="sample_steps"):
        loop(task, promp, setup()[2], sample_steps=1)


def test_rwr_in_place_of_pro():
    task, promp, ds = setup()
    res = loop(task, promp, ds, optimizer=RWR, add_only="all")
    assert len(res.dataset) == 14 and res.metrics[-1]["envs_done"] == 10


def test_bad_options_are_refused_before_any_work(tmp_path):
    task, promp, ds = setup()
    for kw, msg in [
        ({"batch_size": 0}, "batch_size"),
        ({"add_only": "best"}, "add_only"),
        ({"choice": "far"}, "choice"),
        ({"resume": True}, "needs a dir"),
        ({"var_floor": -1.0}, "var_floor"),
        ({"optimizer_kwargs": {**KW, "seed": 1}}, "seed"),
    ]:
        with pytest.raises(ValueError, match=msg):
            loop(task, promp, ds, run_dir=None, **kw)
    with pytest.raises(ValueError, match="empty"):
        loop(task, promp, TrajectoryDataset(promp, 2))


# ----------------------------------------------------------------------------- checkpoints
def test_checkpoints_are_atomic_loadable_and_match_the_csv(tmp_path, monkeypatch):
    task, promp, ds = setup()
    run = tmp_path / "run"
    res = loop(task, promp, ds, run_dir=run)
    model = protorch.load(run)
    assert model.env_map.num_points == len(res.dataset)
    torch.testing.assert_close(
        model.env_map.predict_mean(res.pool[:3]), res.env_map.predict_mean(res.pool[:3])
    )
    rows = list(csv.DictReader((run / METRICS_FILE).open()))
    assert [int(r["step"]) for r in rows] == list(range(4))
    assert not [p.name for p in run.rglob("*.tmp")]  # no temporary file left behind
    with pytest.raises(FileExistsError, match="resume"):
        loop(task, promp, setup()[2], run_dir=run)  # never overwrites a run

    # a crash inside the second checkpoint write leaves the first checkpoint, complete
    import protorch.loop as loop_mod

    calls = {"n": 0}
    real = loop_mod.save_model

    def failing(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError("disk full")
        return real(*a, **k)

    monkeypatch.setattr(loop_mod, "save_model", failing)
    run2 = tmp_path / "run2"
    with pytest.raises(OSError, match="disk full"):
        loop(task, promp, setup()[2], run_dir=run2)
    saved = TrajectoryDataset.load(checkpoint_path(run2))
    assert saved.metadata["loop"]["step"] == 1 and len(saved.metadata["loop"]["tried"]) == 4
    assert [int(r["step"]) for r in csv.DictReader((run2 / METRICS_FILE).open())] == [0, 1]


@pytest.mark.slow
def test_resume_after_a_crash_equals_an_uninterrupted_run(tmp_path):
    task, promp, ds = setup()
    whole = loop(task, promp, ds, num_envs=12, batch_size=3)
    run = tmp_path / "run"
    with pytest.raises(Crash):
        loop(task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, on_step=crash_at_2)
    with pytest.raises(ValueError, match="other settings"):
        loop(task, promp, setup()[2], num_envs=12, batch_size=4, run_dir=run, resume=True)
    # the optimiser's, the map's and the loop's own settings are part of the run, too
    for change, name in (
        (dict(optimizer_kwargs={**KW, "beta": 50.0}), "optimizer_kwargs"),
        (dict(env_map=lambda: make_env_map("torch", 2.0)), "env_map"),
        (dict(env_map=lambda: make_env_map("torch", 1.0, nearest_k=3)), "env_map"),
        (dict(var_floor=1e-3), "var_floor"),
        (dict(eval_dtype=torch.float32), "eval_dtype"),
    ):
        with pytest.raises(ValueError, match=f"other settings.*'{name}'"):
            loop(
                task,
                promp,
                setup()[2],
                num_envs=12,
                batch_size=3,
                run_dir=run,
                resume=True,
                **change,
            )
    # and so is the initial data (other demonstrations)
    with pytest.raises(ValueError, match="initial data set .* is not the one given now"):
        loop(task, promp, setup(5)[2], num_envs=12, batch_size=3, run_dir=run, resume=True)
    other = setup()[2]
    other.mean[0] += 0.1
    with pytest.raises(ValueError, match="initial data set"):
        loop(task, promp, other, num_envs=12, batch_size=3, run_dir=run, resume=True)
    res = loop(task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, resume=True)
    assert res.resumed_from == 2 and res.tried == whole.tried
    assert [r["step"] for r in res.metrics] == list(range(5))
    torch.testing.assert_close(res.dataset.env, whole.dataset.env)
    assert torch.equal(res.dataset.mean, whole.dataset.mean) and torch.equal(
        res.dataset.var, whole.dataset.var
    )
    # resuming a finished run does nothing more
    done = loop(task, promp, setup()[2], num_envs=12, batch_size=3, run_dir=run, resume=True)
    assert done.resumed_from == 4 and len(done.dataset) == len(res.dataset)


SCRIPT = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from test_loop import loop, setup
    task, promp, ds = setup()
    loop(task, promp, ds, num_envs=24, batch_size=2, run_dir={run!r}, resume=True,
         on_step=lambda row: time.sleep(0.15))
    print("finished")
""")


@pytest.mark.slow
def test_sigkill_mid_loop_then_resume_keeps_every_finished_environment(tmp_path):
    run = tmp_path / "run"
    script = tmp_path / "job.py"
    script.write_text(SCRIPT.format(tests=str(ROOT / "tests" / "loop"), run=str(run)))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, str(script)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    ckpt = checkpoint_path(run)
    deadline = time.monotonic() + 45
    before = None
    while time.monotonic() < deadline and proc.poll() is None:
        if ckpt.is_file():
            before = TrajectoryDataset.load(ckpt)
            if before.metadata["loop"]["step"] >= 2:
                break
        time.sleep(0.02)
    assert proc.poll() is None, "the loop finished before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    killed = TrajectoryDataset.load(ckpt)  # what the kill left on disk: a complete checkpoint
    state = killed.metadata["loop"]
    assert 2 <= state["step"] < 12
    out = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0 and "finished" in out.stdout, out.stderr
    final = TrajectoryDataset.load(ckpt)
    fstate = final.metadata["loop"]
    assert fstate["step"] == 12 and sorted(fstate["tried"]) == list(range(24))
    assert fstate["tried"][: len(state["tried"])] == state["tried"]
    # every entry of the killed run's data set is still there, unchanged, in the same place
    m = len(killed)
    torch.testing.assert_close(final.env[:m], killed.env)
    torch.testing.assert_close(final.mean[:m], killed.mean)
    rows = list(csv.DictReader((run / METRICS_FILE).open()))
    assert [int(r["step"]) for r in rows] == list(range(13))  # no duplicated or half rows
