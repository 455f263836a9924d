"""protorch.load: a run folder read without Hydra or OmegaConf (a fresh process that cannot import
either loads a real run and makes a call), the config read as OmegaConf wrote it; one policy, one
answer: mean_trajectory takes one environment, and its class is the one reference starts with."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from dataclasses import fields
from pathlib import Path

import pytest
import torch

from protorch.policy.load import POLICY_FILE, _tuples, read_config, read_policy_record
from tests.control.test_policy import toy_policy
from tests.policy.builders import point_particle_config

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]

NO_HYDRA = textwrap.dedent("""
    import sys, time
    class Block:  # neither may be imported
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("hydra", "omegaconf"):
                raise ImportError(name + " is blocked in this process")
    sys.meta_path.insert(0, Block())
    t0 = time.perf_counter()
    import protorch
    policy = protorch.load(sys.argv[1], planner=sys.argv[2])
    env = policy.task.sample_envs(1)[0]
    policy.reset(env)
    r = policy.reference(env, 0.1)
    assert r.q.shape == (policy.promp.num_dof,) and r.plan_t in (0.0, 0.1)
    policy.close()
    assert not any(m.split(".")[0] in ("hydra", "omegaconf") for m in sys.modules)
    assert not any(m.startswith(("protorch.experiments", "protorch.app")) for m in sys.modules)
    print("ok", round(time.perf_counter() - t0, 2))
""")


@pytest.mark.slow  # a small point_particle run, then a fresh process (torch's import)
def test_load_imports_neither_hydra_nor_omegaconf(tmp_path):
    import protorch
    from protorch.experiments import run_experiment

    cfg = point_particle_config(max_iter=3, samples=10, demo_envs=4, num_envs=6, test=3, episodes=1)
    run_experiment(cfg, tmp_path)
    assert read_policy_record(tmp_path / POLICY_FILE)["experiment"] == "point_particle"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", NO_HYDRA, str(tmp_path), "thread"],
        capture_output=True,
        text=True,
        check=False,
        env=env,
        cwd=ROOT,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")
    # a folder from before policy.json: rebuilt through the experiment's builder, the same policy
    old = tmp_path / "old"
    shutil.copytree(tmp_path, old, ignore=shutil.ignore_patterns("old", "policy.json"))
    new, rebuilt = protorch.load(tmp_path), protorch.load(old)
    assert type(rebuilt.task) is type(new.task) and rebuilt.task.objectives == new.task.objectives
    for pol in (new, rebuilt):
        env = new.task.sample_envs(1, torch.Generator().manual_seed(1))[0]
        pol.reset(env)
    for t in (0.0, 0.5, 1.5):
        a, b = new.reference(env, t), rebuilt.reference(env, t)
        assert torch.equal(a.q, b.q) and torch.equal(a.qd, b.qd) and a.label == b.label
    assert (new.duration, new.decision_dt) == (rebuilt.duration, rebuilt.decision_dt)


def test_the_config_is_read_as_omegaconf_wrote_it(tmp_path):
    """Floats without a dot (``1e-3``) are floats, as OmegaConf reads them, not strings."""
    p = tmp_path / "config.yaml"
    p.write_text(
        "name: arm_reach\ngp:\n  var_floor: 1e-3\n  alpha: 30.0\n  nearest_k: 30\nflag: "
        "true\nnone: null\n"
    )
    assert read_config(p) == {
        "name": "arm_reach",
        "gp": {"var_floor": 1e-3, "alpha": 30.0, "nearest_k": 30},
        "flag": True,
        "none": None,
    }
    p.write_text("- a list\n")
    with pytest.raises(ValueError, match="not a mapping"):
        read_config(p)


@pytest.mark.parametrize("planner", ["inline", "thread"])
def test_mean_trajectory_takes_one_environment_and_answers_as_reference(planner):
    """``mean_trajectory(env (d,))`` is ``(T, D)``, the batch's row for it, and at a fixed
    environment right after ``reset()`` the reference tracks that class and is that trajectory."""
    pol = toy_policy(nearest_k=8, planner=planner, plan_period=1e6)
    envs = torch.rand(12, 2, generator=torch.Generator().manual_seed(4), dtype=F64)
    batch = pol.mean_trajectory(envs)  # (12, T, D)
    labels = set()
    for i, e in enumerate(envs):
        one = pol.mean_trajectory(e)
        assert one.shape == batch.shape[1:]
        torch.testing.assert_close(one, batch[i], rtol=0, atol=1e-12)
        pol.reset()
        T = one.shape[0]
        for k in (0, T // 2, T - 1):
            r = pol.reference(e, k / (T - 1) * pol.duration)
            torch.testing.assert_close(r.q, one[k], rtol=0, atol=1e-9)
        assert r.label == int(pol.labels[pol.first_class(e)])
        labels.add(r.label)
    assert labels == {0, 1}
    pol.close()


def _fields(task) -> dict:
    return {f.name: getattr(task, f.name) for f in fields(task) if f.name != "robot"}


PP_TASK = {"_target_": "protorch.tasks.PointParticleTask", "objectives": "hole"}
DISC_TASK = {"_target_": "examples.reach_around_a_disc.ReachAroundADisc", "radius": 0.2}


@pytest.mark.parametrize(
    "name, task",
    [
        ("point_particle", {**PP_TASK, "fixed_start": [0.0, 5.0], "demo_envs": 4}),
        ("self_improve", {**DISC_TASK, "tol": 0.04, "demo_envs": 4}),
    ],
)
def test_policy_json_builds_the_task_the_experiment_builds(name, task):
    """The record's task class and arguments make the task the experiment's own builder makes
    (every field equal), and its ProMP and policy settings are the experiment's."""
    from protorch.experiments.policy_run import policy_record, rebuild_experiment
    from protorch.tasks import make_task

    cfg = {
        "name": name,
        "seed": 0,
        "plot": False,
        "task": task,
        "settings": {"promp": {"num_basis": 7}, "progress": False},
    }
    if name == "point_particle":  # (self_improve runs no moving test)
        cfg["settings"]["dynamic"] = {"duration": 1.5}
    rec = json.loads(json.dumps(policy_record(cfg)))  # through JSON, as the run writes it
    exp = rebuild_experiment(cfg)
    made = make_task(rec["task"]["class"], **_tuples(rec["task"]["kwargs"]))
    assert type(made) is type(exp.task) and _fields(made) == _fields(exp.task)
    given = {k: v for k, v in task.items() if k not in ("_target_", "demo_envs")}
    assert {k: getattr(made, k) for k in given} == _tuples(given)
    assert rec["promp"] == {"num_dof": 2, "num_basis": 7, "num_steps": 100}
    assert rec["policy"]["duration"] == (1.5 if name == "point_particle" else 1.0)
    assert rec["experiment"] == name


def test_a_bad_policy_json_is_refused_with_one_line(tmp_path):
    (tmp_path / POLICY_FILE).write_text('{"format": 99}')
    with pytest.raises(ValueError, match="format 1 expected, got 99; re-run"):
        read_policy_record(tmp_path / POLICY_FILE)
    (tmp_path / POLICY_FILE).write_text('{"format": 1, "task": {}}')
    with pytest.raises(ValueError, match="without experiment, promp, policy"):
        read_policy_record(tmp_path / POLICY_FILE)
