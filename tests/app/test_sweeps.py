"""Sweeps on real launchers, end to end at a tiny budget: the beta x alpha grid of the
point-particle
experiment (4 configurations) in parallel with joblib and with submitit (local executor, the
SLURM launcher's machinery without a cluster), reported by ``protorch.app.report``; an Optuna study
tuning beta and alpha for held-out success; the SLURM and Optuna presets compose."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app import report as rep
from protorch.app.main import config_dir
from protorch.experiments import run_experiment

optuna = pytest.importorskip("optuna", reason="the sweep extra: pip install -e '.[sweep]'")

ROOT = Path(__file__).resolve().parents[2]
# smaller than the app tests' TINY: four runs must fit in seconds on 2 cores
MICRO = [
    "settings.loop.num_envs=4",
    "settings.loop.batch_size=2",
    "optimizer.max_iter=3",
    "optimizer.num_samples=10",
    "optimizer.relevance_samples=10",
    "settings.test.num_envs=4",
    "settings.dynamic.episodes=1",
    "settings.progress=false",
    "plot=false",
    "settings.baselines=[]",
]
GRID = ["optimizer.beta=10,40", "gp.alpha=1e-3,1e-2"]
PAIRS = {(b, a) for b in (10.0, 40.0) for a in (1e-3, 1e-2)}


def run_cli(args, check=True, env=None, **kw):
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        **(env or {}),
    }  # several runs share 2 cores: one thread each
    proc = subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        **kw,
    )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"exit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
        )
    return proc


def grid_sweep(root: Path, launcher: list[str]) -> Path:
    run_cli(
        ["-m", "experiment=point_particle", *GRID, *MICRO, *launcher, f"hydra.sweep.dir={root}"]
    )
    return root


@pytest.fixture(scope="module")
def joblib_sweep(tmp_path_factory):
    return grid_sweep(
        tmp_path_factory.mktemp("joblib"), ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]
    )


@pytest.fixture(scope="module")
def submitit_sweep(tmp_path_factory):
    return grid_sweep(
        tmp_path_factory.mktemp("submitit"),
        ["hydra/launcher=submitit_local", "hydra.launcher.timeout_min=5"],
    )


def check_grid(root: Path) -> list[dict]:
    runs = sorted(root.glob("*/metrics.json"))
    assert len(runs) == len(PAIRS)
    metrics = [json.loads(p.read_text()) for p in runs]
    pairs = {(m["settings"]["beta"], m["settings"]["alpha"]) for m in metrics}
    assert pairs == PAIRS  # every configuration ran once, with the values it was given
    for m in metrics:
        assert m["objective"]["metric"] == "test.success_rate"
        assert m["objective"]["value"] == m["test"]["success_rate"]
    return metrics


def check_report(root: Path, tmp_path: Path) -> None:
    paths = rep.write_report(rep.collect(root), tmp_path)
    rows = list(csv.DictReader(paths["csv"].open()))
    assert len(rows) == len(PAIRS) and {r["status"] for r in rows} == {"ok"}
    assert {(float(r["optimizer.beta"]), float(r["gp.alpha"])) for r in rows} == PAIRS
    for r in rows:
        m = json.loads((root / r["run"] / "metrics.json").read_text())
        assert float(r["test.success_rate"]) == m["test"]["success_rate"]
        assert float(r["loop.seconds"]) == m["loop"]["seconds"]
        assert float(r["objective.value"]) == m["objective"]["value"]
    md = paths["md"].read_text()
    assert "swept: optimizer.beta, gp.alpha" in md
    assert sum(line.startswith("| ") for line in md.splitlines()) == 1 + len(
        PAIRS
    )  # header + a row per run
    assert paths["png"].stat().st_size > 10_000


def overlapping(metrics: list[dict]) -> bool:
    """Whether two runs were running at the same time (their started..finished intervals meet)."""
    spans = sorted(
        (datetime.fromisoformat(m["run"]["started"]), datetime.fromisoformat(m["run"]["finished"]))
        for m in metrics
    )
    return any(b[0] < a[1] for a, b in zip(spans, spans[1:]))


@pytest.mark.slow
def test_joblib_runs_the_grid_in_parallel_processes(joblib_sweep):
    metrics = check_grid(joblib_sweep)
    pids = {m["run"]["pid"] for m in metrics}
    assert len(pids) >= 2, pids  # the runs were shared out between worker processes
    assert os.getpid() not in pids
    assert overlapping(metrics)  # ... which ran at the same time


@pytest.mark.slow
def test_submitit_runs_the_grid_as_separate_jobs(submitit_sweep):
    metrics = check_grid(submitit_sweep)
    assert len({m["run"]["pid"] for m in metrics}) == len(PAIRS)  # one process per job, as on SLURM
    assert overlapping(metrics)
    logs = list((submitit_sweep / ".submitit").glob("*/*_log.out"))
    assert len(logs) == len(PAIRS)


@pytest.mark.slow
def test_report_of_the_joblib_sweep(joblib_sweep, tmp_path):
    check_report(joblib_sweep, tmp_path)


@pytest.mark.slow
def test_report_of_the_submitit_sweep(submitit_sweep, tmp_path):
    check_report(submitit_sweep, tmp_path)


@pytest.mark.slow
def test_optuna_tunes_beta_and_alpha_for_held_out_success(tmp_path):
    db = tmp_path / "study.db"
    root = tmp_path / "optuna"
    run_cli(
        [
            "-m",
            "experiment=point_particle",
            "tune=point_particle",
            "hydra.sweeper.n_trials=3",
            "hydra.sweeper.sampler.n_startup_trials=2",
            f"hydra.sweeper.storage=sqlite:///{db}",
            "hydra.sweeper.study_name=t",
            *MICRO,
            f"hydra.sweep.dir={root}",
        ]
    )
    study = optuna.load_study(
        study_name="t", storage=f"sqlite:///{db}"
    )  # a stored study (SQLAlchemy < 2)
    trials = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(trials) == 3 and study.direction == optuna.study.StudyDirection.MAXIMIZE
    runs = [json.loads((root / str(t.number) / "metrics.json").read_text()) for t in trials]
    for t, m in zip(trials, runs):
        assert 1 <= t.params["optimizer.beta"] <= 100 and 1e-4 <= t.params["gp.alpha"] <= 1e-1
        assert m["settings"]["beta"] == pytest.approx(t.params["optimizer.beta"])
        assert m["settings"]["alpha"] == pytest.approx(t.params["gp.alpha"])
        assert t.value == m["test"]["success_rate"]  # the app returned the held-out success
    best = OmegaConf.load(root / "optimization_results.yaml")
    assert best.best_value == max(t.value for t in trials)
    r = rep.collect(root)
    assert r.swept == ["optimizer.beta", "gp.alpha"] and r.optuna["best_value"] == best.best_value


# ------------------------------------------------------------------------------ presets
def compose_hydra(*overrides):
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        return compose(
            config_name="config",
            overrides=["experiment=point_particle", *overrides],
            return_hydra_config=True,
        )


def test_slurm_preset_composes_onto_the_submitit_launcher():
    c = compose_hydra(
        "hydra/launcher=slurm", "hydra.launcher.partition=gpu", "hydra.launcher.gpus_per_node=1"
    )
    launcher = c.hydra.launcher
    assert (
        launcher._target_ == "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"
    )
    assert launcher.partition == "gpu" and launcher.gpus_per_node == 1
    assert (
        launcher.cpus_per_task == 2
        and launcher.timeout_min == 60
        and launcher.array_parallelism == 64
    )
    assert launcher.submitit_folder.endswith("/.submitit/%j")  # inside the sweep directory


@pytest.mark.slow
def test_slurm_preset_submits_an_array_job_with_its_resources(tmp_path):
    """A fake ``sbatch`` on PATH keeps the script submitit hands to SLURM (then refuses it)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "sbatch").write_text(
        f'#!/bin/sh\ncp "$1" {tmp_path}/submitted.sh\necho "no cluster here" >&2\nexit 1\n'
    )
    (bin_dir / "srun").write_text("#!/bin/sh\nexit 0\n")  # submitit checks that srun exists
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    proc = run_cli(
        [
            "-m",
            "experiment=point_particle",
            "optimizer.beta=10,20,40",
            *MICRO,
            "hydra/launcher=slurm",
            "hydra.launcher.partition=gpu",
            "hydra.launcher.timeout_min=30",
            f"hydra.sweep.dir={tmp_path / 's'}",
        ],
        check=False,
        env={"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"},
    )
    assert proc.returncode != 0 and "no cluster here" in proc.stderr
    lines = set((tmp_path / "submitted.sh").read_text().splitlines())
    for expected in (
        "#SBATCH --array=0-2%3",
        "#SBATCH --partition=gpu",
        "#SBATCH --cpus-per-task=2",
        "#SBATCH --mem=8GB",
        "#SBATCH --time=30",
        "#SBATCH --job-name=protorch-point_particle",
    ):
        assert expected in lines, expected
    assert any(line.startswith("srun ") and "submitit.core._submit" in line for line in lines)


def test_tune_preset_is_optuna_maximising_held_out_success():
    c = compose_hydra("tune=point_particle")
    assert c.objective == "test.success_rate"
    sweeper = c.hydra.sweeper
    assert sweeper._target_.endswith("OptunaSweeper") and sweeper.direction == "maximize"
    assert sweeper.sampler._target_ == "optuna.samplers.TPESampler"
    assert dict(sweeper.params) == {
        "optimizer.beta": "tag(log, interval(1, 100))",
        "gp.alpha": "tag(log, interval(1e-4, 1e-1))",
    }


# ------------------------------------------------------------------------------ objective
def fig3_cfg(tmp_objective):
    return {
        "name": "fig3_toy",
        "optimizer": {"beta": 10.0, "num_samples": 20, "max_iter": 3},
        "settings": {"eval_samples": 50},
        "plot": False,
        "objective": tmp_objective,
    }


def test_objective_is_stored_and_returned(tmp_path):
    m = run_experiment(fig3_cfg("pro.irrelevant_std_ratio"), tmp_path)
    assert m["objective"] == {
        "metric": "pro.irrelevant_std_ratio",
        "value": m["pro"]["irrelevant_std_ratio"],
    }
    assert json.loads((tmp_path / "metrics.json").read_text())["objective"] == m["objective"]


def test_unknown_objective_names_the_metrics_and_keeps_the_results(tmp_path):
    with pytest.raises(
        ValueError, match=r"objective 'pro.nope': no such metric; numeric metrics .*pro.seconds"
    ):
        run_experiment(fig3_cfg("pro.nope"), tmp_path)
    assert "pro" in json.loads(
        (tmp_path / "metrics.json").read_text()
    )  # the run's work is not lost
    with pytest.raises(ValueError, match="not a number"):
        run_experiment(fig3_cfg("pro.final_std"), tmp_path / "b")


@pytest.mark.parametrize("bad", ["", "a..b", "1abc", 3])
def test_malformed_objective_is_refused_before_any_work(tmp_path, bad):
    with pytest.raises(ValueError, match="objective=.* must be a dotted metrics key"):
        run_experiment(fig3_cfg(bad), tmp_path / "x")
    assert not (tmp_path / "x").exists()
