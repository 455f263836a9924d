"""The physics section of experiment=arm_reach (protorch.experiments.arm_physics): its metrics and
episodes file from a tiny run, re-judged by the independent replay, and its settings refused
before any work."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from protorch.experiments import SettingsError, arm_physics, check_config, run_experiment

from .test_arm_reach import cfg

pytest.importorskip(
    "mujoco",
    minversion="4.0",
    reason="the physics extra is not installed: pip install protorch[physics]",
)
REPLAY = Path(__file__).resolve().parents[2] / "benchmarks" / "replay_physics.py"


def _replay():
    spec = importlib.util.spec_from_file_location("replay_physics", REPLAY)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_tiny_run_writes_physics_metrics_and_episodes_the_replay_agrees_with(tmp_path):
    m = run_experiment(
        cfg("task.collision=volume", "settings.baselines=[]", "task.prior_detours=[]"), tmp_path
    )
    p = m["physics"]
    for section, n in (("test", 6), ("dynamic", 3)):
        s = p[section]
        assert s["episodes"] == n and 0 <= s["success_rate"] <= 1 and 0 <= s["agreement"] <= 1
        assert set(s["failures"]) == {
            "can_contact",
            "table_contact",
            "limits",
            "goal",
            "saturated",
            "diverged",
        }
        f = s["failures"]
        assert (
            max(f["can_contact"], f["table_contact"])
            <= s["contacts"]
            <= f["can_contact"] + f["table_contact"]
        )
        assert s["tracking_rms"] >= 0 and s["max_torque_ratio"] > 0
    assert p["settings"]["collision"] == "volume" and p["dynamic"]["map_queries"] > 0
    assert (
        m["seconds"]["physics"] == p["seconds"] > 0 and "physics_render" not in m["seconds"]
    )  # plot=false
    with np.load(tmp_path / p["episodes_file"]) as f:
        e = {k: f[k] for k in f.files}
    steps = int(round((1.0 + 0.2) / 0.02)) + 1
    assert e["q"].shape == (9, steps, 7) and e["can"].shape == e["target"].shape == (9, steps, 2)
    assert e["contact"].shape == (9, steps) and e["success"].shape == e["moving"].shape == (9,)
    assert e["moving"].tolist() == [False] * 6 + [True] * 3 and float(e["dt"]) == 0.02
    assert e["success"].mean() == pytest.approx(
        (p["test"]["success_rate"] * 6 + p["dynamic"]["success_rate"] * 3) / 9
    )
    res = _replay().replay(tmp_path / p["episodes_file"])
    assert res["held-out"]["contradicted"] == 0 and res["moving"]["contradicted"] == 0
    assert res["held-out"]["successes"] + res["moving"]["successes"] == int(e["success"].sum())


@pytest.mark.parametrize(
    "override, match",
    [
        ("settings.physics.kd=1000.0", r"kp dt\^2 / mass \+ 2 kd dt / mass < 4"),
        ("settings.physics.timestep=0.003", "whole multiple of the physics timestep"),
        (
            "settings.physics.run=sometimes",
            "settings.physics.run='sometimes' must be one of auto, always, never",
        ),
        ("settings.physics.mass_scale=0", "settings.physics.mass_scale=0 must be a number > 0"),
        (
            "settings.physics.feasible_scale=1.5",
            "settings.physics.feasible_scale=1.5 must be a number > 0 and <= 1",
        ),
        (
            "settings.physics.feasible_scale=0",
            "settings.physics.feasible_scale=0 must be a number > 0 and <= 1",
        ),
        ("settings.physics.feasible=maybe", "settings.physics.feasible"),
    ],
)
def test_bad_physics_settings_are_refused_before_any_work(override, match):
    with pytest.raises(SettingsError, match=match):
        check_config(cfg(override))


def test_without_mujoco_auto_skips_with_one_line_and_always_refuses(monkeypatch, capsys):
    def missing():
        raise arm_physics.MujocoMissing(
            'the physics test needs MuJoCo >= 4.0: pip install "protorch[physics]"'
        )

    monkeypatch.setattr(arm_physics, "load_mujoco", missing)
    monkeypatch.setattr(arm_physics, "mujoco_available", lambda: False)
    with pytest.raises(SettingsError, match=r'pip install "protorch\[physics\]"'):
        check_config(cfg("settings.physics.run=always"))
    check_config(cfg())  # auto: the run goes on

    class Exp:
        physics_cfg = {**arm_physics.PHYSICS_DEFAULTS}

    assert arm_physics.physics_section(Exp(), None, Path("."), False) == {
        "skipped": 'MuJoCo is not installed: pip install "protorch[physics]"'
    }
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [
        '[protorch] physics test skipped: MuJoCo is not installed: pip install "protorch[physics]"'
    ]
    never = type("Never", (), {"physics_cfg": {**arm_physics.PHYSICS_DEFAULTS, "run": "never"}})()
    assert arm_physics.physics_section(never, None, Path("."), False) == {
        "skipped": "physics.run=never"
    }
