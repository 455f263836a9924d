"""The arm experiment (Sec. IV-C) end to end at a tiny budget: the paper's settings in the config,
metrics, checkpoint with both classes, both labels-off baselines, resume, and bad settings."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import protorch
from protorch.app.main import config_dir
from protorch.data.checkpoint import checkpoint_path
from protorch.data.dataset import TrajectoryDataset
from protorch.experiments import run_experiment
from protorch.experiments.arm_reach import prepare
from protorch.tasks.arm.reach import LEFT, RIGHT

TINY = [
    "settings.loop.num_envs=10",
    "settings.loop.batch_size=5",
    "optimizer.max_iter=3",
    "optimizer.num_samples=20",
    "optimizer.relevance_samples=20",
    "task.priors=30",
    "task.demo_envs=2",
    "settings.test.num_envs=6",
    "settings.dynamic.episodes=3",
    "settings.dynamic.duration=1.0",
    "settings.dynamic.hold=0.2",
    "settings.progress=false",
    "plot=false",
]


# for a run whose MuJoCo episodes are not under test (they are in test_arm_physics.py)
NO_PHYSICS = "settings.physics.run=never"


def cfg(*overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        c = compose(config_name="config", overrides=["experiment=arm_reach", *TINY, *overrides])
    plain = OmegaConf.to_container(c, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(
        OmegaConf.create(plain), resolve=True
    )  # baseline_optimizer: ${optimizer.*}


def prepared(c: dict, **task):
    """:func:`prepare` on the settings ``c`` (:func:`cfg`) without dynamic episodes; ``task``
    overrides keys of ``c["task"]``."""
    s = c["settings"]
    return prepare(
        optimizer=c["optimizer"],
        task=c["task"] | task if task else c["task"],
        gp=c["gp"],
        promp=s["promp"],
        loop=s["loop"],
        test=s["test"],
        dynamic={"episodes": 0},
    )


def test_config_holds_the_papers_settings():
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        full = compose(config_name="config", overrides=["experiment=arm_reach"])
    assert (
        full.optimizer.beta == 200
        and full.optimizer.max_iter == 50
        and full.optimizer.num_samples == 100
    )
    assert full.settings.loop.num_envs == 2024 and full.task.priors == 2004
    assert full.task.demo_envs == 20 and full.task.demos_per_env == 3
    assert full.settings.test.num_envs == 200 and full.settings.dynamic.episodes == 100
    assert list(full.settings.dynamic.moves) == [1, 2] and full.settings.loop.labels is True
    assert full.gp.alpha > 0 and full.gp.nearest_k == 30
    assert full.task.prior_grid == "rectangles" and full.task.region == "rectangles"


@pytest.mark.slow
def test_tiny_run_writes_metrics_checkpoint_and_baselines(tmp_path):
    # the skeleton keeps every straight prior, so the counts below are the grid's (the volume
    # default's clearing and detours: test_prepare_builds_labelled_demonstrations_and_priors)
    m = run_experiment(cfg("task.collision=skeleton", NO_PHYSICS), tmp_path)
    assert m["loop"]["seconds"] > 0  # a duration, not a rate (over 1 s on a loaded machine)
    for path in (
        ("test", "success_rate"),
        ("dynamic", "success_rate"),
        ("baselines", "labels_off", "test", "success_rate"),
        ("baselines", "labels_off", "dynamic", "success_rate"),
        ("baselines", "labels_off_loop", "test", "success_rate"),
        ("baselines", "labels_off_loop", "dynamic", "success_rate"),
    ):
        v = m
        for k in path:
            v = v[k]
        assert isinstance(v, float) and 0.0 <= v and (v <= 1.0 or path[-1] == "seconds"), (
            path
        )  # a rate, or a time
    assert isinstance(m["dynamic"]["switches"], int) and m["dynamic"]["episodes"] == 3
    assert (
        m["baselines"]["labels_off"]["dynamic"]["switches"] == 0
    )  # one class: nothing to switch to
    assert m["test"]["num_envs"] == 6 and m["loop"]["envs_tried"] == 10
    assert m["loop"]["refill"] is True  # loop.refill=auto as the loop resolved it for PRO
    assert m["demos"]["count"] == 6 and m["demos"]["left"] > 0 and m["demos"]["right"] > 0
    assert m["priors"]["count"] == 30 and m["priors"]["left"] + m["priors"]["right"] == 30
    assert m["priors"]["grid"]["over"] == "rectangles" and m["priors"]["grid"]["kept"] == 30
    assert not {"region", "table", "rectangles"} & set(
        m["test"]
    )  # only the rectangles' test by default
    assert {
        "demonstrations",
        "priors",
        "loop",
        "evaluation",
        "labels_off",
        "labels_off_loop",
        "total",
    } <= set(m["seconds"])
    assert json.loads((tmp_path / "metrics.json").read_text())["test"] == m["test"]
    model = protorch.load(tmp_path)  # the trained map, both classes kept apart
    assert set(torch.unique(model.env_map.labels).tolist()) == {LEFT, RIGHT}
    assert model.task_name == "arm_reach" and model.promp.num_dof == 7
    off = protorch.load(tmp_path / "baselines" / "labels_off_loop")
    assert torch.unique(off.env_map.labels).tolist() == [0]
    # a finished run resumes at once, unchanged; without resume it is refused
    again = run_experiment(cfg("task.collision=skeleton", NO_PHYSICS, "resume=true"), tmp_path)
    assert again["loop"]["resumed_from"] == again["loop"]["steps"] and again["test"] == m["test"]
    with pytest.raises(FileExistsError, match="resume=true"):
        run_experiment(cfg(), tmp_path)
    # the trained map scored on other held-out environments and episodes (fresh evaluation seeds)
    other = run_experiment(
        cfg(
            "task.collision=skeleton",
            NO_PHYSICS,
            "resume=true",
            "+settings.test.seed=12345",
            "+settings.dynamic.seed=54321",
        ),
        tmp_path,
    )
    assert other["loop"]["resumed_from"] == other["loop"]["steps"]
    assert other["test"]["seed"] == 12345 and other["dynamic"]["seed"] == 54321
    assert m["test"]["seed"] != 12345 and m["dynamic"]["seed"] != 54321


@pytest.mark.parametrize(
    "override, match",
    [
        ("+task.colour=red", "^task.colour is not a setting of task"),
        ("task.margin=-0.1", "^task.margin=-0.1 must be a number >= 0 or null$"),
        ("gp.alpha=0", "^gp.alpha=0 must be a number > 0$"),
        ("settings.loop.labels=maybe", "^settings.loop.labels='maybe' must be true or false$"),
        ("+settings.threads=0", "^settings.threads=0 must be an int >= 1 or null$"),
        (
            "+settings.dynamic.speed=2",
            "^settings.dynamic.speed is not a setting of settings.dynamic",
        ),
        (
            "settings.baselines=[labels_of]",
            r"^settings.baselines\[0\]='labels_of' must be one of labels_off, labels_off_loop$",
        ),
        ("+settings.test.seed=0", r"test.seed \(0\) must differ from the training seeds"),
        ("+settings.dynamic.seed=0", r"dynamic.seed \(0\) must differ from the training seeds"),
        ("+settings.dynamic.seed=abc", "^settings.dynamic.seed='abc' must be an int >= 0$"),
        ("task.prior_grid=room", "^task.prior_grid='room' must be one of rectangles, table$"),
        ("task.region=floor", "^task.region='floor' must be one of rectangles, table$"),
        ("task.demos=/no/such/folder", "^task.demos='/no/such/folder': no such folder"),
        ("+gp.neighbours=16", "^gp.neighbours applies to gp=sparse only, not to gp=torch$"),
        ("task.prior_clear=maybe", "^task.prior_clear must be true, false or auto, got 'maybe'$"),
        (
            "task.prior_detours=[0.2,-0.1]",
            r"^task.prior_detours must hold distances > 0 \(m\), got -0.1$",
        ),
    ],
)
def test_bad_settings_are_refused_before_any_work(tmp_path, override, match):
    with pytest.raises((ValueError, TypeError, FileNotFoundError), match=match):
        run_experiment(cfg(override), tmp_path)
    assert not checkpoint_path(tmp_path).exists()


@pytest.mark.slow
def test_gp_sparse_runs_the_same_loop_as_the_exact_maps_nearest_k(tmp_path):
    """The arm's map is the authors' local GPs (gp.nearest_k = 30): gp=sparse finds the same
    neighbours with its k-d tree and solves the same systems, so the whole run is the same (the
    detour priors kept: without them no moving episode switches class, and the switch rates are
    NaN)."""
    runs = {}
    for gp in ("torch", "sparse"):
        m = run_experiment(cfg(f"gp={gp}", "settings.baselines=[]", NO_PHYSICS), tmp_path / gp)
        runs[gp] = m
        assert protorch.load(tmp_path / gp).env_map.backend == gp
    for key in ("test", "dynamic", "demos", "priors"):
        assert runs["sparse"][key] == runs["torch"][key], key
    loops = [
        {k: v for k, v in runs[gp]["loop"].items() if "second" not in k}
        for gp in ("torch", "sparse")
    ]
    assert loops[0] == loops[1]


@pytest.mark.slow
def test_prepare_builds_labelled_demonstrations_and_priors():
    assert cfg()["task"]["collision"] == "volume"  # the default plans with the volumes
    c = cfg("task.collision=skeleton")  # every straight prior kept
    setup = prepared(c)
    data = setup.initial_data()
    assert len(data) == 2 + 30 and data.label[:2].tolist() == [
        LEFT,
        RIGHT,
    ]  # one entry per env and side
    assert torch.equal(data.label[2:], setup.prior_labels)
    assert torch.equal(setup.initial_data(labels=False).label, torch.zeros(32, dtype=torch.long))
    # the prior's straight path passes the can on the side its label says
    traj = setup.promp.trajectory(setup.prior_mean)
    assert torch.equal(setup.task.side(traj, setup.prior_envs), setup.prior_labels)


def test_volume_task_keeps_only_the_priors_clear_of_the_can_under_its_volumes():
    c = cfg("task.collision=volume", "task.priors=60")

    def setup(clear):
        return prepared(c, prior_clear=clear, prior_detours=[])

    auto, every = setup("auto"), setup(False)
    assert (
        auto.prior_clear is True
        and every.prior_envs.shape[0] == 60
        and "clear" not in every.prior_report
    )
    ok = every.task.success(every.promp.trajectory(every.prior_mean), every.prior_envs)  # (60,)
    assert 0 < int(ok.sum()) < 60  # the filter has something to drop and something to keep
    assert auto.prior_report["clear"] == int(ok.sum()) == auto.prior_envs.shape[0]
    assert torch.equal(auto.prior_envs, every.prior_envs[ok]) and torch.equal(
        auto.prior_labels, every.prior_labels[ok]
    )
    assert bool(auto.task.success(auto.promp.trajectory(auto.prior_mean), auto.prior_envs).all())
    assert len(auto.initial_data()) == 2 + int(ok.sum())
    assert cfg()["task"]["prior_clear"] == "auto" and cfg()["task"]["prior_detours"] == "auto"
    # the detour priors (tests/tasks/arm/test_priors.py) come after the straight ones kept
    with_detours = prepared(c)
    assert (
        with_detours.prior_detours == (0.18, 0.24)
        and sum(with_detours.prior_report["detours"].values()) > 0
    )
    assert torch.equal(with_detours.prior_envs[: auto.prior_envs.shape[0]], auto.prior_envs)


@pytest.mark.slow
def test_loop_over_the_table_grid_iterates_the_initial_data_and_tests_both_regions(tmp_path):
    c = cfg(
        "task.prior_grid=table",
        "settings.loop.choice=dataset",
        "settings.loop.num_envs=12",
        "settings.baselines=[labels_off]",
        "task.collision=skeleton",
        NO_PHYSICS,
    )  # every straight prior kept: 30
    assert c["task"]["prior_grid"] == "table" and c["settings"]["loop"]["choice"] == "dataset"
    m = run_experiment(c, tmp_path)
    grid = m["priors"]["grid"]
    assert grid["over"] == "table" and grid["kept"] == 30 and m["priors"]["count"] == 30
    assert (
        grid["too_close"]
        + grid["goal_out_of_reach"]
        + grid["can_on_start_posture"]
        + grid["ik_failed"]
        + grid["valid"]
        == grid["nodes"]
    )
    assert m["settings"]["prior_grid"] == "table" and m["settings"]["region"] == "rectangles"
    assert m["loop"]["envs_tried"] == 12
    # the held-out test over the rectangles (the main one) and over the table, for every map
    for t in (m["test"], m["baselines"]["labels_off"]["test"]):
        assert t["region"] == "rectangles" and t["num_envs"] == 6 and t["table"]["num_envs"] == 6
        assert 0.0 <= t["table"]["success_rate"] <= 1.0
    # the loop's environments are the data set's own: the 2 demonstrated ones, then grid nodes
    setup = prepared(c)
    grid_envs = setup.task.prior_grid(30, over="table")
    assert torch.equal(setup.prior_envs, grid_envs)
    ds = TrajectoryDataset.load(checkpoint_path(tmp_path))
    data = ds.env[ds.origin == 2].double()  # (L, 4) the learned entries' environments
    assert data.shape[0] == m["loop"]["added"] > 0
    initial = torch.cat([setup.demo_envs, grid_envs])
    assert bool(
        (torch.cdist(data, initial).amin(1) < 1e-6).all()
    )  # (nodes lie 10 cm or more apart)


def test_the_skeleton_can_objective_reaches_the_task_from_the_config(gen):
    """task.can_objective=skeleton: the experiment's task reads the skeleton in the can objective
    (the benchmark's choice, docs/peers.md 3d) and the end effector in the other two."""
    c = cfg("task.can_objective=skeleton", "task.collision=skeleton")
    setup = prepared(c)
    task = setup.task
    assert task.can_objective == "skeleton" and task.collision == "skeleton"
    env = task.sample_envs(3, gen)  # (3, 4)
    traj = setup.promp.trajectory(setup.prior_mean[:3])  # (3, T, 7)
    idx = task.cost_indices(traj.shape[-2])
    near = task.can_distance(traj[:, idx], env)  # (3,)
    c_sk = task.costs(traj, env)
    c_ee = dataclasses.replace(task, can_objective="ee").costs(traj, env)
    torch.testing.assert_close(c_sk[:, [0, 2]], c_ee[:, [0, 2]])
    d = c_sk[:, 0] - (task.ee_path(traj[:, idx])[:, 0] - task.start_position()).norm(
        dim=-1
    )  # the deviation
    torch.testing.assert_close(c_sk[:, 1], task.clearance - near.clamp(max=task.clearance) + d)


def test_plan_margin_is_the_loops_margin_and_the_tests_keep_margin():
    c = cfg("task.priors=20", "task.plan_margin=0.03")
    setup = prepared(c, prior_detours=[])
    assert (
        setup.task.margin == 0.01 and setup.loop_task.margin == 0.03
    )  # the volumes' test margin is kept
    assert (
        setup.loop_task.kinematics is setup.task.kinematics
    )  # the same arm, only the margin differs
    traj = setup.promp.trajectory(setup.prior_mean)
    gap = setup.task.can_gap(traj, setup.prior_envs)  # (P,)
    assert torch.equal(
        setup.loop_task.success(traj, setup.prior_envs),
        setup.task.success(traj, setup.prior_envs) & (gap > 0.03),
    )
    with pytest.raises(ValueError, match="task.plan_margin"):
        prepared(c, plan_margin=-0.01)
