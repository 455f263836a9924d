"""The experiment skeleton (protorch.experiments.loop_run) with a subclass of its own, and
the benchmarks' settings helper (benchmarks/configs.py)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from protorch.data.checkpoint import checkpoint_path
from protorch.experiments.point_particle import prepare
from protorch.experiments.self_improve import GenericExperiment

ROOT = Path(__file__).resolve().parents[2]
DISC = "examples.reach_around_a_disc.ReachAroundADisc"
TINY = dict(
    optimizer={
        "name": "pro",
        "beta": 50.0,
        "max_iter": 4,
        "num_samples": 12,
        "relevance_samples": 12,
    },
    task={"_target_": DISC, "demo_envs": 4},
    gp={"alpha": 5.0},
    promp={"num_basis": 5, "num_steps": 30},
    loop={"num_envs": 6, "batch_size": 3},
    test={"num_envs": 8},
)


class Twice(GenericExperiment):
    """The generic experiment with a loop baseline that runs the method's own loop again."""

    baseline_names = ("demos_only", "again")
    loop_baselines = frozenset({"again"})


@pytest.fixture
def on_path():
    sys.path.insert(0, str(ROOT))
    yield
    sys.path.remove(str(ROOT))


def test_a_loop_baseline_runs_in_its_own_folder_and_repeats_the_seeded_loop(tmp_path, on_path):
    m = Twice(**TINY).run(tmp_path, baselines=["again", "demos_only"], plot=False)
    assert (
        checkpoint_path(tmp_path).is_file()
        and checkpoint_path(tmp_path / "baselines" / "again").is_file()
    )
    again = m["again"]  # baseline_section None: at the top level, like demos_only
    timing = ("seconds",)
    assert {k: v for k, v in again["loop"].items() if k not in timing} == {
        k: v for k, v in m["loop"].items() if k not in timing
    }
    assert again["test"] == {k: v for k, v in m["test"].items() if k != "seed"}
    assert set(m["demos_only"]) == {"test"}  # no moving test: no "dynamic" entry
    assert m["loop"]["envs_tried"] == 6 and m["demos"]["count"] == 12
    # a second run without resume is refused before any work, naming the baseline's checkpoint too
    checkpoint_path(tmp_path).unlink()
    with pytest.raises(FileExistsError, match="baselines/again"):
        Twice(**TINY).run(tmp_path, baselines=["again"], plot=False)
    assert not checkpoint_path(tmp_path).exists()


def test_an_unknown_baseline_is_refused_naming_the_choices(tmp_path, on_path):
    with pytest.raises(
        ValueError, match=r"unknown baseline\(s\) \['nope'\]; choose from \['demos_only', 'again'\]"
    ):
        Twice(**TINY).run(tmp_path, baselines=["nope"], plot=False)
    assert not checkpoint_path(tmp_path).exists()


def test_the_benchmarks_read_the_composed_config():
    spec = importlib.util.spec_from_file_location(
        "bench_configs", ROOT / "benchmarks" / "configs.py"
    )
    configs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(configs)
    s = configs.experiment_settings(
        "point_particle",
        ["settings.loop.num_envs=1", "settings.dynamic.episodes=0", "settings.test.num_envs=3"],
    )
    # values from the groups (conf/optimizer/pro.yaml, rwr.yaml, conf/task) that the experiment file
    # lacks
    assert s["optimizer"]["name"] == "pro" and s["optimizer"]["num_samples"] == 100
    assert s["optimizer"]["beta"] == 20.0 and s["baseline_optimizer"]["name"] == "rwr"
    assert s["baseline_optimizer"]["beta"] == 20.0 and s["task"]["demos"] == "synthetic"
    setup = prepare(**configs.arguments_of(prepare, s))
    assert (
        setup.optimizers["pro"][1]["num_samples"] == 100
        and setup.optimizers["rwr"][0].__name__ == "RWR"
    )
    assert len(setup.demos) == 90 and setup.test_envs.shape[0] == 3 and setup.loop.num_envs == 1
    with pytest.raises(TypeError, match="takes \\*\\*kwargs"):
        configs.arguments_of(lambda **kw: None, s)
