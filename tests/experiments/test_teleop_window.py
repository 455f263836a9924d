"""experiment=teleop_window: bad input refused before any work; a tiny run end to end."""

import pytest

from protorch.experiments import SettingsError, teleop_window

OPT = {
    "name": "pro",
    "beta": 50.0,
    "num_samples": 12,
    "max_iter": 2,
    "tol": 0.0,
    "relevance_samples": 12,
}


def _run(tmp_path, **kw):
    return teleop_window.run(tmp_path / "run", optimizer=OPT, **kw)


@pytest.mark.parametrize(
    "teleop, message",
    [
        ({"conditions": ["none", "sometimes"]}, "unknown condition 'sometimes'"),
        ({"operator": "nowhere.py:Op"}, "no file nowhere.py"),
        ({"operators": 0}, "teleop.operators"),
        ({"wall": {"speed": 1.0}}, "unknown wall setting"),
    ],
)
def test_bad_settings_are_refused_with_one_line_before_any_work(tmp_path, teleop, message):
    with pytest.raises(SettingsError, match=message) as info:
        _run(tmp_path, teleop=teleop)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "run").exists()


def test_an_operator_without_the_protocol_or_returning_nan_is_refused(tmp_path):
    path = tmp_path / "ops.py"
    path.write_text(
        "import math\n\nclass Lazy:\n    def __init__(self, seed):\n        pass\n\n"
        "class Nan(Lazy):\n    def reset(self, start, end, wall):\n        pass\n\n"
        "    def act(self, t, pose, wall):\n        return [math.nan] * 7\n"
    )
    with pytest.raises(SettingsError, match="class Lazy lacks reset, act"):
        _run(tmp_path, teleop={"operator": f"{path}:Lazy"})
    with pytest.raises(SettingsError, match="Nan.act returned a non-finite pose"):
        _run(tmp_path, teleop={"operator": f"{path}:Nan"})


@pytest.mark.slow
def test_a_tiny_run_measures_the_three_conditions_and_the_freedom(tmp_path):
    m = _run(
        tmp_path,
        demos={"envs": 4, "per_env": 2},
        loop={"num_envs": 2, "batch_size": 2},
        promp={"num_steps": 50},
        freedom_optimizers=["cem"],
        teleop={"operators": 3, "dt": 0.05, "time_limit": 6.0},
    )
    assert set(m["teleop"]) == {"none", "fixed", "adaptive"}
    for cond, r in m["teleop"].items():
        assert set(r) >= {"success_rate", "collision_rate", "time", "effort", "freedom"}
        assert r["success_rate"] + r["collision_rate"] <= 1.0 + 1e-12
    assert m["teleop"]["none"]["effort"] == 0.0 and m["teleop"]["none"]["freedom"] == 1.0
    assert 0 < m["teleop"]["adaptive"]["freedom"] < 1 and m["teleop"]["adaptive"]["effort"] > 0
    assert set(m["freedom"]) == {"pro", "cem"}
    assert m["freedom"]["pro"]["freedom"] == m["teleop"]["adaptive"]["freedom"]  # the same trials
