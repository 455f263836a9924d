"""Your own task from the command line: a task module written into a temporary folder (outside
protorch), run through the whole pipeline by ``experiment=self_improve task._target_=...``, then
``protorch.load`` on the run; the task protocol's error names the missing member."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import protorch
from protorch.tasks import SelfImprovementTask, check_task_protocol, task_class

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "reach_around_a_disc.py"
TINY = [
    "settings.loop.num_envs=6",
    "settings.loop.batch_size=3",
    "optimizer.max_iter=4",
    "optimizer.num_samples=12",
    "optimizer.relevance_samples=12",
    "settings.test.num_envs=8",
    "task.demo_envs=4",
    "settings.promp.num_basis=5",
    "settings.promp.num_steps=30",
    "plot=false",
]


def cli(args, tmp_path, check=True):
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)]),
        "OMP_NUM_THREADS": "1",
    }
    proc = subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}")
    return proc


@pytest.mark.slow
def test_a_task_outside_protorch_runs_the_whole_pipeline(tmp_path):
    (tmp_path / "my_disc_task.py").write_text(
        EXAMPLE.read_text()
    )  # a module protorch has never seen
    run = tmp_path / "run"
    cli(
        [
            "experiment=self_improve",
            "task._target_=my_disc_task.ReachAroundADisc",
            "+task.radius=0.12",
            "gp.alpha=5",
            "optimizer.beta=50",
            *TINY,
            f"hydra.run.dir={run}",
        ],
        tmp_path,
    )
    m = json.loads((run / "metrics.json").read_text())
    assert m["task"] == "my_disc_task.ReachAroundADisc"
    assert m["settings"]["alpha"] == 5.0 and m["loop"]["envs_tried"] == 6
    for rate in (m["test"]["success_rate"], m["demos_only"]["test"]["success_rate"]):
        assert 0.0 <= rate <= 1.0
    assert m["loop"]["seconds"] > 0 and m["test"]["num_envs"] == 8
    sys.path.insert(
        0, str(tmp_path)
    )  # the policy rebuilds the run's task: its module must be importable
    try:
        model = protorch.load(run)  # the checkpoint rebuilds the map
        task = task_class("my_disc_task.ReachAroundADisc")(radius=0.12)
    finally:
        sys.path.remove(str(tmp_path))
    assert (
        model.env_map.num_points
        == m["loop"]["dataset_size"]
        == m["demos"]["envs"] + m["loop"]["added"]
    )
    envs = task.sample_envs(8, torch.Generator().manual_seed(2_000_003), dtype=torch.float64)
    ok = task.success(
        model.mean_trajectory(envs), envs
    )  # the loaded map reproduces the run's test number
    assert float(ok.double().mean()) == m["test"]["success_rate"]


@pytest.mark.slow
def test_a_task_missing_a_member_is_refused_naming_it(tmp_path):
    (tmp_path / "half_task.py").write_text(
        "class Half:\n    name = 'half'\n    num_dof = 2\n    env_dim = 1\n"
        "    def costs(self, traj, env): ...\n    def success(self, traj, env): ...\n"
    )
    proc = cli(
        [
            "experiment=self_improve",
            "task._target_=half_task.Half",
            f"hydra.run.dir={tmp_path / 'r'}",
        ],
        tmp_path,
        check=False,
    )
    assert proc.returncode != 0
    assert "lacks sample_envs, demonstrations" in proc.stderr
    assert not (tmp_path / "r" / "metrics.json").exists()


def test_the_example_follows_the_protocol():
    sys.path.insert(0, str(ROOT))
    try:
        task = task_class("examples.reach_around_a_disc.ReachAroundADisc")()
    finally:
        sys.path.remove(str(ROOT))
    assert isinstance(task, SelfImprovementTask)
    check_task_protocol(task)
    demos, envs = task.demonstrations(5, 3, torch.Generator().manual_seed(0))
    assert len(demos) == 15 and envs.shape == (15, 4) and demos[0].shape == (100, 2)
    traj = torch.stack(demos)  # (15, T, 2)
    assert task.costs(traj, envs).shape == (15, 3) and task.success(traj, envs).dtype == torch.bool


def test_an_unknown_task_path_is_a_clear_error():
    with pytest.raises(ValueError, match="cannot import 'no_such_module'"):
        task_class("no_such_module.Task")


def test_a_task_breaking_its_contract_is_refused_before_any_work_and_leaves_no_folder(tmp_path):
    from protorch.experiments import run_experiment
    from protorch.tasks import TaskContractError

    (tmp_path / "summed_task.py").write_text(
        "from examples.reach_around_a_disc import ReachAroundADisc\n\n"
        "class Summed(ReachAroundADisc):\n    def costs(self, traj, env):\n        return "
        "super().costs(traj, env).sum(-1)\n"
    )
    sys.path[:0] = [str(tmp_path), str(ROOT)]
    try:
        cfg = {
            "name": "self_improve",
            "seed": 0,
            "threads": 1,
            "plot": False,
            "task": {"_target_": "summed_task.Summed", "demo_envs": 3},
            "optimizer": {"name": "pro", "beta": 10.0},
        }
        with pytest.raises(
            TaskContractError,
            match=r"costs\(traj \(9, 100, 2\), env \(9, 4\)\) returned shape \(9,\)",
        ):
            run_experiment(cfg, tmp_path / "run")
    finally:
        del sys.path[:2]
    assert not (tmp_path / "run").exists()
