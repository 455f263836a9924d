"""``python -m protorch --help`` and a bare ``python -m protorch``: the experiments and
their keys."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from protorch.app.help import (
    GROUPS,
    chosen_experiment,
    experiment_lines,
    first_sentence,
    group_choices,
    help_text,
    key_meanings,
    wants_help,
)
from protorch.app.main import config_dir

ROOT = Path(__file__).resolve().parents[2]
CONF = config_dir()


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _unwrapped(text: str) -> str:
    return " ".join(text.split())


def test_help_lists_every_choice_of_every_group_with_its_whole_first_sentence():
    text = _unwrapped(help_text(CONF, ["--help"]))
    for group, _ in GROUPS:
        names = sorted(p.stem for p in (CONF / group).glob("*.yaml"))
        lines = group_choices(CONF, group)
        assert sorted(lines) == names and names
        assert f"{group}=NAME" in text
        for name, first in lines.items():
            assert first and f"{name} {first}" in text  # wrapped, never cut
            assert first.endswith((".", ")")) or group in ("tune", "experiment"), (
                group,
                name,
                first,
            )
    assert {"epro", "pro", "cmaes"} <= set(
        group_choices(CONF, "optimizer")
    ) and "custom" in group_choices(CONF, "task")
    lines = experiment_lines(CONF)
    assert lines["fig4_window"].startswith("Fig. 4:") and lines["point_particle"].startswith(
        "Sec. IV-B"
    )
    assert "--cfg job" in text and "key=value" in text


def test_first_sentence_spans_lines_and_abbreviations(tmp_path):
    y = tmp_path / "x.yaml"
    y.write_text(
        "# @package _global_\n# Sec. IV-C: an arm (Ewerton et al. 2019) reaches\n# around a can. "
        "Then more.\nname: x\n"
    )
    assert first_sentence(y) == "Sec. IV-C: an arm (Ewerton et al. 2019) reaches around a can."
    y.write_text("# Your own task, the whole pipeline:\n#   python -m protorch ...\nname: x\n")
    assert first_sentence(y) == "Your own task, the whole pipeline"


def test_help_lines_fit_the_terminal_and_keep_every_word():
    text = help_text(CONF, ["experiment=point_particle", "--help"])
    assert max(len(line) for line in text.splitlines()) <= 120
    rows = key_meanings(CONF / "experiment" / "point_particle.yaml")
    flat = _unwrapped(text)
    assert all(_unwrapped(m) in flat for _, _, m in rows if m)


def test_key_meanings_are_dotted_by_indentation_and_continue_onto_comment_lines():
    rows = {k: (v, m) for k, v, m in key_meanings(CONF / "experiment" / "point_particle.yaml")}
    assert rows["gp.alpha"] == ("1.0e-03", "kernel exp(-alpha ||e - e'||^2) on the 6-D environment")
    assert rows["settings.loop.batch_size"][0] == "100"
    # a two-line comment is one meaning
    assert rows["optimizer.convergence"][1].endswith("best clearance >= 0.1")
    shared = {k: m for k, _, m in key_meanings(CONF / "config.yaml")}
    assert "threads" in shared and shared["plot"] == "write PNG figures"
    assert not any(k.startswith("hydra") or k.startswith("defaults") for k in shared)


def test_which_command_lines_get_the_help():
    assert wants_help([]) and wants_help(["--help"]) and wants_help(["experiment=fig3_toy", "-h"])
    assert wants_help(["seed=1"])  # names no experiment: nothing to run
    assert not wants_help(["experiment=fig3_toy"]) and not wants_help(
        ["-m", "experiment=fig3_toy", "seed=1,2"]
    )
    assert not wants_help(["--hydra-help"]) and not wants_help(["--info"])
    assert chosen_experiment(["+experiment=arm_reach"]) == "arm_reach"
    assert chosen_experiment(["experiment=null"]) is None


@pytest.mark.slow
def test_bare_command_prints_the_help_and_exits_0_without_running(tmp_path):
    proc = _cli(f"hydra.run.dir={tmp_path / 'run'}")
    assert proc.returncode == 0, proc.stderr
    assert (
        "experiment=NAME" in proc.stdout
        and "fig4_window" in proc.stdout
        and "optimizer=NAME" in proc.stdout
    )
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_help_of_one_experiment_lists_its_keys_meanings():
    proc = _cli("experiment=point_particle", "--help")
    assert proc.returncode == 0, proc.stderr
    assert "settings of experiment=point_particle" in proc.stdout
    assert (
        "settings.loop.batch_size=100" in proc.stdout and "B environments inferred" in proc.stdout
    )
    bad = _cli("experiment=nope", "--help")
    assert bad.returncode == 0 and "unknown experiment 'nope'" in bad.stdout


def test_help_lists_the_robot_group_and_the_arm_experiments_robot_settings():
    text = help_text(CONF, ["experiment=arm_reach", "--help"])
    assert "robot=NAME" in text and "  panda " in text and "  custom " in text
    for key in (
        "robot.urdf=???",
        "robot.end_link=null",
        "robot.home=null",
        "robot.max_acceleration=10.0",
        "robot.capsules=auto",
    ):
        assert key in text, key
    assert "robot.urdf=???" not in help_text(CONF, ["experiment=point_particle", "--help"])
