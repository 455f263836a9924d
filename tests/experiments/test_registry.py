"""One experiment registry: each experiment one class with its hooks, the app's experiment configs
and the registry name the same experiments, and no module outside the registry compares
experiment names (a task class's own ``name`` is the task's identity and may say it)."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

from protorch.experiments import EXPERIMENTS, SettingsError, check_config
from protorch.experiments.registry import REGISTRY, Experiment, experiment, for_task
from protorch.experiments.summary import HEADLINES, Headline
from protorch.tasks import TASKS

ROOT = Path(__file__).resolve().parents[2]


def test_the_registry_names_the_apps_experiments_and_each_has_its_hooks():
    assert set(REGISTRY) == {p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml")}
    assert EXPERIMENTS == {name: e.run for name, e in REGISTRY.items()}
    assert HEADLINES == {name: e.headlines for name, e in REGISTRY.items()}
    for name, e in REGISTRY.items():
        assert issubclass(e, Experiment) and e.name == name
        assert "out_dir" in inspect.signature(e.run).parameters
        assert e.headlines and all(isinstance(h, Headline) for h in e.headlines)
        if e.task is not None:
            assert TASKS[e.task.name] is e.task
        if e.policy is not None:  # a self-improvement run: the policy's hooks
            assert callable(getattr(e.policy, "configure", None))
            assert set(e.policy_settings({})) >= {"duration", "decision_dt", "switch_margin"}
    assert [n for n, e in REGISTRY.items() if e.policy] == [
        "point_particle",
        "arm_reach",
        "self_improve",
    ]
    assert {n: e.scene for n, e in REGISTRY.items() if e.scene} == {
        "point_particle": "particle",
        "arm_reach": "arm",
    }


def test_lookups_by_name_and_by_task():
    assert experiment("arm_reach") is REGISTRY["arm_reach"]
    with pytest.raises(SettingsError, match="experiment='nope' must be one of arm_reach, "):
        experiment("nope")
    with pytest.raises(SettingsError, match="experiment='nope' must be one of"):
        check_config({"name": "nope"})
    assert for_task("arm_reach") is REGISTRY["arm_reach"]
    assert for_task("point_particle") is REGISTRY["point_particle"]
    assert for_task("window") is None and for_task("nope") is None  # no policy runs


def test_the_arm_policy_settings_carry_its_velocity_command_and_hysteresis():
    arm = REGISTRY["arm_reach"].policy_settings({"switch_clearance": 0.01}, duration=2.0)
    assert arm["switch_clearance"] == 0.01 and arm["duration"] == 2.0 and "kp" in arm
    pp = REGISTRY["point_particle"].policy_settings({"kp": 1000.0})
    assert "kp" not in pp and pp["duration"] == 2.0  # the particle's moving test's default


def test_task_kwargs_are_what_the_experiments_pass():
    pp = REGISTRY["point_particle"].task_kwargs(
        {"task": {"objectives": ["clearance"], "demo_envs": 3, "fixed_start": [0, 5]}}
    )
    assert pp == {"objectives": ("clearance",), "fixed_start": (0, 5)}
    arm = REGISTRY["arm_reach"].task_kwargs(
        {"task": {"_target_": "x", "priors": 3, "margin": 0.01, "demos": "synthetic"}}
    )
    assert arm == {"margin": 0.01, "robot": None}
    generic = REGISTRY["self_improve"].task_kwargs(
        {"task": {"_target_": "m.C", "demos": "generate", "demo_envs": 3, "size": [1, 2]}}
    )
    assert generic == {"size": (1, 2)}


def _name_literals(path: Path, names: set[str]) -> list[str]:
    """``path:line`` of every string constant equal to an experiment name, but a task class's own
    ``name: str = "..."`` and an ``__all__`` entry (a function's name)."""
    tree = ast.parse(path.read_text())
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", "") == "name":
            skip.add(id(node.value))
        if isinstance(node, ast.Assign) and any(
            getattr(t, "id", "") == "__all__" for t in node.targets
        ):
            skip |= {id(e) for e in getattr(node.value, "elts", [])}
    return [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and node.value in names and id(node) not in skip
    ]


def test_no_module_but_the_registry_compares_experiment_names():
    found = []
    for path in sorted((ROOT / "protorch").rglob("*.py")):
        if path != ROOT / "protorch" / "experiments" / "registry.py":
            found += _name_literals(path, set(REGISTRY))
    assert not found, found
