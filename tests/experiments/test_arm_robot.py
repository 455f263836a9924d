"""The arm experiment on a user's own robot (robot=custom): the settings reach every layer from
the command line alone, and each bad robot input is refused before any work (one line naming the
setting, exit 2, no run folder)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app.main import config_dir
from protorch.experiments import SettingsError, check_config
from tests.robots.user_arm import user_arm_home, user_arm_urdf, write_user_arm

ROOT = Path(__file__).resolve().parents[2]
HOME = "[" + ",".join(map(str, user_arm_home())) + "]"


def cfg(*overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        c = compose(config_name="config", overrides=["experiment=arm_reach", *overrides])
    plain = OmegaConf.to_container(c, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def custom(urdf, *more):
    """``robot=custom`` with the user's arm; ``more`` overrides (a ``robot.`` key replaces the
    default's)."""
    keys = {"robot.urdf": str(urdf), "robot.end_link": "tool0", "robot.home": HOME}
    keys |= dict(m.split("=", 1) for m in more)
    return cfg("robot=custom", *(f"{k}={v}" for k, v in keys.items()))


def test_the_robot_group_reaches_the_experiment(tmp_path):
    assert cfg()["robot"]["base"] == "panda" and check_config(cfg())["robot"]["base"] == "panda"
    urdf = write_user_arm(tmp_path)
    kwargs = check_config(custom(urdf, "settings.physics.run=never"))
    assert kwargs["robot"]["urdf"] == str(urdf) and kwargs["robot"]["end_link"] == "tool0"
    assert kwargs["robot"]["home"] == user_arm_home()
    # the Panda's own settings can be changed one by one
    assert check_config(cfg("robot.max_acceleration=5.0"))["robot"]["max_acceleration"] == 5.0


@pytest.mark.parametrize(
    "make, overrides, line",
    [
        (
            lambda p: _write(p, "<robot><link name="),
            (),
            r"robot\.urdf=.*bad\.urdf is not valid XML",
        ),
        (
            lambda p: write_user_arm(p),
            ("robot.end_link=tool9",),
            r"robot\.end_link='tool9' is not a link",
        ),
        (
            lambda p: write_user_arm(p),
            ("robot.home=[0,0,0]",),
            r"robot\.home=\[0, 0, 0\] must be 6 joint angles",
        ),
        (
            lambda p: write_user_arm(p),
            ("robot.home=[0,0,4,0,0,0]",),
            r"robot\.home has 4\.0 for joint 'elbow', outside",
        ),
        (
            lambda p: _write(p, user_arm_urdf(fixed=("wrist_1",))),
            ("robot.home=[0,0,0,0,0]",),
            r"robot\.end_link='tool0': the chain of .* has 5 joints",
        ),
        (
            lambda p: _write(p, user_arm_urdf(inertials=False)),
            ("settings.physics.run=always",),
            r"link 'shoulder' \(moved by joint 'shoulder_pan'\) has no <inertial>",
        ),
        (
            lambda p: _write(p, user_arm_urdf(scale=0.5)),
            (
                "task.goal_box=[[0.66,0.74],[-0.24,0.24]]",
                "task.can_box=[[0.50,0.62],[-0.12,0.12]]",
                "task.table=[[0.2,0.9],[-0.5,0.5]]",
                "task.can_radius=0.0375",
                "task.can_height=0.23",
            ),
            r"task\.goal_box: the target \(0\.660, -0\.240\) .* out of "
            r"the my_arm arm's reach",
        ),
        (
            lambda p: write_user_arm(p),
            ("task.goal_box=[[0.66,1.4],[-0.2,0.2]]",),
            r"goal_box .* must lie on the table",
        ),
        (
            lambda p: write_user_arm(p),
            ("robot.capsules=none",),
            r"collision=volume needs the robot's capsules: my_arm has none \(robot\.capsules",
        ),
        (
            lambda p: write_user_arm(p),
            ("robot.capsules=none", "task.collision=skeleton", "settings.physics.run=always"),
            r"robot\.capsules: the my_arm arm has no collision volumes",
        ),
    ],
)
def test_bad_robot_input_is_refused_before_any_work(tmp_path, make, overrides, line):
    urdf = make(tmp_path)
    with pytest.raises(SettingsError, match=line) as exc:
        check_config(custom(urdf, *overrides))
    assert "\n" not in str(exc.value)


def test_without_inertials_the_kinematic_run_is_allowed(tmp_path):
    urdf = _write(tmp_path, user_arm_urdf(inertials=False))
    assert check_config(custom(urdf, "settings.physics.run=never"))["robot"]["urdf"] == str(urdf)


def test_task_urdf_points_to_the_robot_setting():
    with pytest.raises(
        SettingsError, match=r"task\.urdf is now robot\.urdf: robot=custom robot\.urdf=PATH"
    ):
        check_config({**cfg(), "task": {**cfg()["task"], "urdf": "x.urdf"}})


def cli(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=900,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


@pytest.mark.slow
def test_a_bad_robot_on_the_command_line_exits_2_without_a_run_folder(tmp_path):
    write_user_arm(tmp_path)
    proc = cli(
        [
            "experiment=arm_reach",
            "robot=custom",
            "robot.urdf=my_arm.urdf",
            "robot.end_link=tool0",
            "robot.home=[0,0,0]",
            "hydra.run.dir=out",
        ],
        tmp_path,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error: robot.home=[0, 0, 0] must be 6 joint angles")
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_users_own_urdf_runs_the_arm_experiment_with_physics_from_the_command_line(tmp_path):
    pytest.importorskip("mujoco")
    write_user_arm(tmp_path)  # not shipped with protorch: 6 joints, collision cylinders, inertials
    proc = cli(
        [
            "experiment=arm_reach",
            "robot=custom",
            "robot.urdf=my_arm.urdf",
            "robot.end_link=tool0",
            f"robot.home={HOME}",
            "settings.loop.num_envs=10",
            "task.priors=10",
            "task.prior_detours=[0.18]",
            "task.demo_envs=2",
            "settings.test.num_envs=6",
            "settings.dynamic.episodes=2",
            "settings.dynamic.duration=1.0",
            "settings.dynamic.hold=0.2",
            "settings.baselines=[]",
            "settings.physics.run=always",
            "settings.physics.render=false",
            "settings.progress=false",
            "optimizer.max_iter=3",
            "optimizer.num_samples=20",
            "optimizer.relevance_samples=20",
            "hydra.run.dir=out",
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "out"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["robot"]["name"] == "my_arm" and metrics["robot"]["joints"] == 6
    with np.load(run / "physics" / "episodes.npz") as f:
        assert (
            f["q"].shape[-1] == 6 and f["q"].shape[0] == 6 + 2
        )  # held-out + moving episodes, 6 joints
    assert (run / "arm_3d.png").is_file()


def _write(folder: Path, text: str) -> Path:
    path = folder / "bad.urdf"
    path.write_text(text)
    return path
