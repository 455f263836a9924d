"""Typed settings: a wrong type or range fails within seconds, before any work, with one line
naming the full key, the value and what is allowed (no traceback unless HYDRA_FULL_ERROR=1)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app.main import config_dir
from protorch.experiments import check_config
from protorch.experiments.arm_reach import ArmReachExperiment
from protorch.experiments.settings import (
    OPTIMIZER_SCHEMAS,
    PointParticleSettings,
    SettingsError,
    describe,
)
from protorch.optim import OPTIMIZERS

ROOT = Path(__file__).resolve().parents[2]

BAD = [
    ("settings.loop.num_envs=abc", "settings.loop.num_envs='abc' must be an int >= 0"),
    ("optimizer.beta=abc", "optimizer.beta='abc' must be a number > 0"),
    ("optimizer.beta=[1,2]", "optimizer.beta=[1, 2] must be a number > 0"),
    ("baseline_optimizer.center=foo", "baseline_optimizer.center='foo' must be one of new, old"),
    ("settings.test.num_envs=0", "settings.test.num_envs=0 must be an int >= 1"),
    ("gp.nearest_k=1.5", "gp.nearest_k=1.5 must be an int >= 1 or null"),
    ("task.objectives=holes", "task.objectives='holes' must be one of clearance, hole"),
]


def cli(args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.slow
@pytest.mark.parametrize("override, line", BAD)
def test_a_bad_value_is_one_line_and_no_results(override, line, tmp_path):
    proc = cli(["experiment=point_particle", override, f"hydra.run.dir={tmp_path}"])
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"error: {line}"
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "metrics.json").exists() and not (tmp_path / "config.yaml").exists()
    assert not (tmp_path / "checkpoint").exists()


@pytest.mark.slow
def test_hydra_full_error_shows_the_traceback(tmp_path):
    proc = cli(
        ["experiment=point_particle", "optimizer.beta=abc", f"hydra.run.dir={tmp_path}"],
        env={"HYDRA_FULL_ERROR": "1"},
    )
    assert proc.returncode != 0 and "Traceback" in proc.stderr and "SettingsError" in proc.stderr


def test_every_registered_optimizer_is_checked():
    base = {"name": "point_particle", "optimizer": {}}
    for name in OPTIMIZERS:
        with pytest.raises(SettingsError, match="^optimizer.no_such_key is not a setting"):
            check_config({**base, "optimizer": {"name": name, "no_such_key": 1}})
    with pytest.raises(SettingsError, match="^optimizer.name='nope' must be one of"):
        check_config({**base, "optimizer": {"name": "nope"}})


def test_every_key_has_a_one_line_meaning():
    helps = describe(PointParticleSettings, "settings")
    helps.update(
        {k: v for s in OPTIMIZER_SCHEMAS.values() for k, v in describe(s, "optimizer").items()}
    )
    assert "settings.loop.num_envs" in helps and "optimizer.relevance_samples" in helps
    assert all(v and "\n" not in v for v in helps.values())


@pytest.mark.parametrize(
    "task, line",
    [
        ({"demos": 3}, "task.demos=3 must be a string"),
        ({"priors": -1}, "task.priors=-1 must be an int >= 0"),
        ({"region": "floor"}, "task.region='floor' must be one of rectangles, table"),
        ({"demo": "x"}, "task.demo is not a setting of task"),
    ],
)
def test_the_arm_tasks_settings_are_typed(task, line):
    with pytest.raises(SettingsError) as exc:
        check_config({"name": "arm_reach", "optimizer": {"beta": 200.0}, "task": task})
    assert str(exc.value).startswith(line)


def test_the_arm_configs_task_group_passes_its_schema(tmp_path):
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        c = compose(
            config_name="config", overrides=["experiment=arm_reach", f"task.demos={tmp_path}"]
        )
    kwargs = check_config(OmegaConf.to_container(c, resolve=True))
    assert kwargs["task"]["demos"] == str(tmp_path) and kwargs["task"]["priors"] == 2004
    with pytest.raises(FileNotFoundError, match=r"task.demos='/no/such/folder': no such folder"):
        ArmReachExperiment(optimizer={"beta": 200.0}, task={"demos": "/no/such/folder"})
