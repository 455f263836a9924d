"""benchmarks/studies/external at tiny budgets, on a stand-in for fancy_gym's episodes (fancy_gym
lives in
its own venv: only the test at the end needs it, and skips without it)."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from . import ROOT, benchmark_module

sys.path.insert(0, str(ROOT / "benchmarks" / "external"))


@pytest.fixture(scope="module")
def run():
    with benchmark_module("studies/external/run.py", "external_run", also=("tasks",)) as mod:
        yield mod


@pytest.fixture(scope="module")
def table():
    with benchmark_module("studies/external/table.py", "external_table") as mod:
        yield mod


class Quadratic:
    """Episodes of a stand-in task: return ``-|w - 1|^2``, success below a cost of ``thr``; keeps
    every batch it evaluated."""

    def __init__(self, run_mod, thr: float) -> None:
        from tasks import Outcome

        self.outcome, self.thr, self.batches = Outcome, thr, []

    def __call__(self, weights, context):
        self.batches.append((np.array(weights), context))
        cost = ((np.asarray(weights) - 1.0) ** 2).sum(-1)  # (S,)
        return [self.outcome(-float(c), bool(c < self.thr)) for c in cost]


@pytest.mark.parametrize("name", ["EPRO", "CMAES", "CEM", "PRO"])
def test_run_one_counts_episodes_and_the_best_sample(run, name):
    ev = Quadratic(run, thr=3.0)
    opt = run.make_optimizer(name, 4, 1.0, 10, seed=0)
    partials = []
    res = run.run_one(opt, ev, context=7, budget=205, eval_every=50, progress=partials.append)
    samples = [
        b for b, _ in ev.batches if b.shape[0] > 1
    ]  # the optimiser's asks; the checks of the mean are single
    checks = [b for b, _ in ev.batches if b.shape[0] == 1]
    assert {c for _, c in ev.batches} == {7}  # every episode in the run's context
    assert res["episodes"] == sum(b.shape[0] for b in samples) <= 205
    assert (
        res["episodes"] > 205 - samples[-1].shape[0] * 2
    )  # stopped only when the next ask would not fit
    all_w = np.concatenate(samples)
    costs = ((all_w - 1.0) ** 2).sum(-1)
    assert res["best_return"] == pytest.approx(-costs.min())
    assert res["best_at"] == int(costs.argmin()) + 1
    hit = np.flatnonzero(costs < 3.0)
    assert res["first_success"] == (int(hit[0]) + 1 if hit.size else None)
    eps = [c["episodes"] for c in res["curve"]]
    assert (
        eps == sorted(eps)
        and eps[0] == 0
        and eps[-1] == res["episodes"]
        and len(checks) == len(eps)
    )
    final = ((checks[-1][0] - 1.0) ** 2).sum()  # the last check is the final mean
    assert len(partials) == len(eps) - 1 and all(
        p["partial"] for p in partials
    )  # every check but the last
    assert [p["episodes"] for p in partials] == eps[:-1] and "partial" not in res
    assert res["final_return"] == pytest.approx(-final)


def test_epro_variants_and_overrides(run):
    opt = run.make_optimizer("EPRO:nogate", 3, 0.5, 10, seed=0, epro={"ess": 0.3})
    assert (
        opt.evidence_level is None
        and opt.ess == 0.3
        and float(opt.var[0, 0]) == pytest.approx(0.25)
    )
    assert run.parse_overrides(["ess=0.5", "curvature=false", "x=abc"]) == {
        "ess": 0.5,
        "curvature": False,
        "x": "abc",
    }
    with pytest.raises(SystemExit, match="unknown EPRO variant"):
        run.make_optimizer("EPRO:nope", 3, 1.0, 10, seed=0)
    diag = run.make_optimizer("CMAES:diag", 3, 1.0, 10, seed=0)
    assert diag.strategies[0].opts["CMA_diagonal"] is True


def _run(task, opt, ctx, seed, returns, successes, episodes_each=100):
    curve = [
        {
            "episodes": e,
            "mean_return": r,
            "mean_success": s,
            "mean_pos_dist": 0.1,
            "mean_rot_dist": 0.2,
            "best_return": r,
            "any_success": s,
        }
        for e, r, s in zip(
            range(0, episodes_each * len(returns), episodes_each), returns, successes
        )
    ]
    first = next((c["episodes"] for c in curve if c["mean_success"]), None)
    return {
        "task": task,
        "optimizer": opt,
        "context": ctx,
        "seed": seed,
        "episodes": curve[-1]["episodes"],
        "first_success": first,
        "stopped": None,
        "curve": curve,
    }


def test_table_reads_each_run_at_the_budget(table, tmp_path):
    runs = [
        _run("box_pushing", "EPRO", 1, 0, [-200, -150, -100], [False, False, True]),
        _run("box_pushing", "EPRO", 2, 0, [-210, -190, -180], [False, False, False]),
        _run("box_pushing", "CMAES", 1, 0, [-200, -120, -60], [False, True, True]),
    ]
    path = tmp_path / "r.json"
    path.write_text(
        json.dumps(
            {
                "meta": {"commit": "abc", "command": "python benchmarks/studies/external/run.py x"},
                "runs": runs,
            }
        )
    )
    loaded, _ = table.load([str(path)])
    rows = {line.split(" | ")[1]: line for line in table.summary(loaded, 200)[2:]}
    assert "| 1 / 2 |" in rows["EPRO"] and "-140.0" in rows["EPRO"]  # medians of -100 and -180
    assert (
        "| 1 / 1 |" in rows["CMAES"] and "| 100 |" in rows["CMAES"]
    )  # its first success at episode 100
    mid = {line.split(" | ")[1]: line for line in table.summary(loaded, 100)[2:]}
    assert (
        "| 0 / 2 |" in mid["EPRO"] and "-170.0" in mid["EPRO"]
    )  # read at 100 episodes, not at the end
    doc = tmp_path / "d.md"
    doc.write_text("a\n<!-- t -->\nold\n<!-- /t -->\nb\n")
    table.main([str(path), "--at", "200", "--doc", str(doc), "--marker", "t"])
    text = doc.read_text()
    assert text.startswith(
        'a\n<!-- t -->\n<!-- measured: commit=abc command="python '
        "benchmarks/studies/external/table.py "
    )
    assert "-->\n| task" in text and "old" not in text and text.endswith("<!-- /t -->\nb\n")
    assert "runs at commit(s) abc" in text
    cut = {**_run("box_pushing", "EPRO", 3, 0, [-100, -90], [False, False]), "partial": True}
    lines = {line.split(" | ")[1]: line for line in table.curve([*loaded, cut], [0, 200])[2:]}
    assert "| EPRO | 2 | -205.0 | -140.0 |" in lines["EPRO"]  # the partial run counts nowhere


def test_via_point_reacher_returns_are_finite():
    pytest.importorskip("fancy_gym")
    from tasks import make_env, run_episode

    env = make_env("via_point_reacher")
    out = run_episode(env, np.zeros(env.action_space.shape[0]), 1)
    assert math.isfinite(out.ret) and out.ret < 0


def test_resume_keeps_finished_runs_of_the_same_settings(run, tmp_path):
    meta = {
        "commit": "abc",
        "episodes": 100,
        "samples": 20,
        "start_std": 1.0,
        "epro": {},
        "pro_beta": 0.05,
    }
    runs = [
        {"context": 1, "episodes": 100},
        {"context": 2, "episodes": 40, "partial": True},
        {"context": 3, "episodes": 100, "commit": "def"},
    ]
    path = tmp_path / "r.json"
    assert run.resumed(str(path), {**meta, "eval_every": 10}) == []  # no file: nothing to keep
    path.write_text(json.dumps({"meta": meta, "runs": runs}))
    kept = run.resumed(
        str(path), {**meta, "commit": "new", "eval_every": 10}
    )  # eval_every unknown to the file
    assert [(r["context"], r["commit"]) for r in kept] == [
        (1, "abc"),
        (3, "def"),
    ]  # the partial run is dropped
    with pytest.raises(SystemExit, match="other settings.*episodes=100"):
        run.resumed(str(path), {**meta, "episodes": 200, "eval_every": 10})


@pytest.mark.parametrize("task", ["via_point_reacher", "hole_reacher"])
def test_speed_up_keeps_every_episode_bit_for_bit(task):
    pytest.importorskip("fancy_gym")
    from tasks import make_env

    plain, fast = make_env(task, fast=False), make_env(task, fast=True)
    assert type(fast.unwrapped) is not type(plain.unwrapped)  # the sped-up class is in place
    rng = np.random.default_rng(3)
    for k in range(12):  # small and large weights: some episodes collide, some do not
        w = rng.standard_normal(plain.action_space.shape[0]) * (0.3 if k % 2 else 3.0)
        plain.reset(seed=k % 3)
        fast.reset(seed=k % 3)
        a, b = plain.step(w), fast.step(w)
        assert a[1] == b[1] and np.array_equal(a[0], b[0]) and a[2:4] == b[2:4]
        assert a[4]["trajectory_length"] == b[4]["trajectory_length"]
        for key in ("is_success", "is_collided", "end_effector"):
            assert np.array_equal(np.asarray(a[4][key]), np.asarray(b[4][key]))
