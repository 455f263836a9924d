"""The Hydra app: configs compose, every experiment runs end to end, sweeps and the wheel work."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app.main import config_dir

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = sorted(p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml"))

# Tiny budgets, so every experiment runs end to end in seconds.
TINY = {
    "fig3_toy": ["optimizer.max_iter=5", "optimizer.num_samples=20", "settings.eval_samples=100"],
    "fig4_window": [
        "optimizer.max_iter=3",
        "optimizer.num_samples=20",
        "optimizer.relevance_samples=20",
        "baseline_optimizer.relevance_iters=2",
        "baseline_optimizer.theta_samples=4",
        "baseline_optimizer.trajectory_samples=3",
    ],
    "beam_window": [
        "optimizer.max_iter=3",
        "optimizer.num_samples=20",
        "optimizer.relevance_samples=20",
        "settings.num_demos=4",
        "settings.eval_samples=50",
        "settings.teleop.trials=5",
    ],
    "point_particle": [
        "settings.loop.num_envs=20",
        "settings.loop.batch_size=10",
        "optimizer.max_iter=10",
        "optimizer.num_samples=20",
        "optimizer.relevance_samples=20",
        "settings.test.num_envs=10",
        "settings.dynamic.episodes=3",
        "settings.progress=false",
    ],
    "arm_reach": [
        "settings.loop.num_envs=10",
        "settings.loop.batch_size=10",
        "optimizer.max_iter=3",
        "optimizer.num_samples=20",
        "optimizer.relevance_samples=20",
        "task.priors=10",
        "task.demo_envs=2",
        "settings.test.num_envs=6",
        "settings.dynamic.episodes=2",
        "settings.dynamic.duration=1.0",
        "settings.dynamic.hold=0.2",
        "settings.baselines=[labels_off]",
        "settings.progress=false",
        # the volume default's detour priors at one distance, and the physics episodes without their
        # pictures (made in a subprocess, and what it writes is not read here:
        # tests/sim/test_render.py)
        "task.prior_detours=[0.18]",
        "settings.physics.render=false",
    ],
    "teleop_window": [
        "optimizer.max_iter=2",
        "optimizer.num_samples=12",
        "optimizer.relevance_samples=12",
        "settings.demos.envs=4",
        "settings.demos.per_env=2",
        "settings.loop.num_envs=2",
        "settings.loop.batch_size=2",
        "settings.promp.num_steps=50",
        "settings.teleop.operators=3",
        "settings.teleop.dt=0.05",
        "settings.teleop.time_limit=6.0",
        "settings.freedom_optimizers=[]",
    ],
    "self_improve": [
        "task._target_=examples.reach_around_a_disc.ReachAroundADisc",
        "settings.loop.num_envs=6",
        "settings.loop.batch_size=3",
        "optimizer.max_iter=4",
        "optimizer.num_samples=12",
        "optimizer.relevance_samples=12",
        "settings.test.num_envs=8",
        "task.demo_envs=4",
    ],
}


# the pictures an experiment must write besides its *.png (each over 10 kB)
FIGURES = {
    "point_particle": (
        "success_vs_iteration.png",
        "test_grid.png",
        "online_frames.png",
        "online_episode.gif",
    )
}


def run_cli(args, cwd=ROOT, env=None, check=True):
    proc = subprocess.run(
        [sys.executable, "-m", "protorch", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"exit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
        )
    return proc


def test_every_experiment_has_a_tiny_budget_here():
    assert EXPERIMENTS and set(EXPERIMENTS) == set(TINY)


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_config_composes(name):
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        cfg = compose(config_name="config", overrides=[f"experiment={name}"])
    assert cfg.name == name
    assert float(cfg.optimizer.beta) > 0
    assert cfg.seed == 0 and cfg.dtype in ("float32", "float64")


@pytest.mark.slow
@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_runs_end_to_end_at_a_tiny_budget(name, tmp_path):
    run_cli([f"experiment={name}", *TINY[name], f"hydra.run.dir={tmp_path}"])
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["experiment"] == name
    assert (tmp_path / "config.yaml").is_file()
    pngs = list(tmp_path.glob("*.png"))
    assert pngs and all(p.stat().st_size > 10_000 for p in pngs)
    for figure in FIGURES.get(name, ()):
        assert (tmp_path / figure).stat().st_size > 10_000, figure
        if figure.endswith(".gif"):
            assert (tmp_path / figure).read_bytes()[:6] in (b"GIF87a", b"GIF89a"), figure


def test_bad_beta_is_refused_with_a_clear_error(tmp_path):
    proc = run_cli(
        ["experiment=fig3_toy", "optimizer.beta=-1", f"hydra.run.dir={tmp_path}"], check=False
    )
    assert proc.returncode != 0
    assert "optimizer.beta=-1 must be a number > 0" in proc.stderr
    assert not (tmp_path / "metrics.json").exists()


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["basic", "joblib"])
def test_beta_sweep(launcher, tmp_path):
    args = [
        "-m",
        "experiment=fig4_window",
        "optimizer.beta=1,10,20",
        *TINY["fig4_window"],
        "plot=false",
        f"hydra.sweep.dir={tmp_path}",
    ]
    if launcher == "joblib":
        args += ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]
    run_cli(args)
    runs = sorted(tmp_path.glob("*/metrics.json"))
    assert len(runs) == 3
    betas = sorted(float(OmegaConf.load(p.parent / "config.yaml").optimizer.beta) for p in runs)
    assert betas == [1.0, 10.0, 20.0]


@pytest.mark.slow
def test_app_runs_from_a_built_wheel_outside_the_source_tree(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(wheels),
            str(ROOT),
        ],
        check=True,
        capture_output=True,
        timeout=600,
    )
    (wheel,) = wheels.glob("protorch-*.whl")
    site = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--target", str(site), str(wheel)],
        check=True,
        capture_output=True,
        timeout=600,
    )
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    where = subprocess.run(
        [
            sys.executable,
            "-c",
            "import protorch, protorch.app.main as m; print(protorch.__file__); "
            "print(m.config_dir()); "
            "from protorch.robots import load_robot; from protorch.robots.kinematics import "
            "ArmKinematics; "
            "assert ArmKinematics().num_joints == 7; print(load_robot('panda').urdf)",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert len(where) == 3 and where[2].endswith("panda.urdf")  # the URDF ships inside the wheel
    assert all(Path(p).is_relative_to(site) for p in where), (
        where
    )  # the wheel's copy, configs inside it
    run_cli(["experiment=fig3_toy", *TINY["fig3_toy"], "hydra.run.dir=out"], cwd=work, env=env)
    assert json.loads((work / "out" / "metrics.json").read_text())["experiment"] == "fig3_toy"


@pytest.mark.slow
def test_run_prints_a_summary_last_and_refuses_another_experiments_folder(tmp_path):
    proc = run_cli(
        ["experiment=fig4_window", *TINY["fig4_window"], "plot=false", f"hydra.run.dir={tmp_path}"]
    )
    last = proc.stdout.strip().splitlines()
    assert last[0] == "[protorch] fig4_window summary" and "relevance time" in proc.stdout
    assert "84.5 s" in proc.stdout and last[-1] == f"  run folder {tmp_path}"
    log = (
        tmp_path / "main.log"
    ).read_text()  # the run's log: its start, then the summary, with times
    assert "[protorch] fig4_window: seed 0" in log and all(line in log for line in last)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    proc = run_cli(
        ["experiment=point_particle", *TINY["point_particle"], f"hydra.run.dir={tmp_path}"],
        check=False,
    )
    assert proc.returncode == 2 and "holds results of experiment 'fig4_window'" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.strip().splitlines()[-1].startswith(
        "error: "
    )
    after = {
        p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file() and p.name != "main.log"
    }
    assert after == {k: v for k, v in before.items() if k != "main.log"}


@pytest.mark.slow
def test_a_failed_run_says_failed_once_with_its_traceback_in_main_log(tmp_path):
    proc = run_cli(
        [
            "experiment=point_particle",
            *TINY["point_particle"],
            "task.demos=/nonexistent/demos",
            f"hydra.run.dir={tmp_path}",
        ],
        check=False,
    )
    assert proc.returncode == 1
    assert "FAILED" in proc.stderr.strip().splitlines()[-1]
    out = proc.stdout + proc.stderr
    assert out.count("no such folder") == 1 and "Traceback" not in out  # printed once
    assert json.loads((tmp_path / "status.json").read_text())["status"] == "failed"
    assert "Traceback" in (tmp_path / "main.log").read_text()
    assert not (tmp_path / "metrics.json").exists()


BROKEN_TASKS = {  # a task breaking its contract, and what the one line must name
    "Summed": (
        "return super().costs(traj, env).sum(-1)",
        "costs(traj (12, 100, 2), env (12, 4)) returned shape (12,); it must return (12, O) with O "
        ">= 1",
    ),
    "Negative": (
        "return super().costs(traj, env) - 1.0",
        "costs(traj (12, 100, 2), env (12, 4)) returned -1",
    ),
    "NotBroadcasting": (
        "return super().costs(traj, env.expand(traj.shape[0], 4))",
        "costs(traj (12, 2, 100, 2), env (12, 1, 4)) raised",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(BROKEN_TASKS))
def test_a_task_breaking_its_contract_is_refused_in_one_line_and_leaves_no_folder(name, tmp_path):
    body, expected = BROKEN_TASKS[name]
    (tmp_path / "broken.py").write_text(
        "from examples.reach_around_a_disc import ReachAroundADisc\n\n"
        f"class {name}(ReachAroundADisc):\n    def costs(self, traj, env):\n        {body}\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    proc = run_cli(
        [
            "experiment=self_improve",
            f"task._target_=broken.{name}",
            "task.demo_envs=4",
            "hydra.run.dir=runs/refused",
        ],
        cwd=tmp_path,
        env=env,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stdout == "" and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: task broken.{name}: ") and expected in proc.stderr
    assert not (tmp_path / "runs").exists()  # no run folder, not even an empty one


CHOLESKY = (
    "import hashlib, torch; a = torch.randn(70, 70, generator=torch.Generator().manual_seed(0), "
    "dtype=torch.float64); a = a @ a.T + 70 * torch.eye(70, dtype=torch.float64); "
    "print(hashlib.sha256(torch.linalg.cholesky(a).numpy().tobytes()).hexdigest())"
)


def _python(code: str, **env_vars) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("MKL_CBWR", "ATEN_CPU_CAPABILITY")}
    env.update(PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", **env_vars)
    return (
        subprocess.run(
            [sys.executable, "-c", code],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            check=True,
            timeout=600,
        )
        .stdout.strip()
        .splitlines()[-1]
    )


@pytest.mark.slow
def test_the_app_pins_mkl_before_its_first_call():
    # the app sets MKL_CBWR after protorch's imports: they must not have called MKL yet
    pinned = _python(
        "from protorch.app.main import pin_mkl_code_path; assert pin_mkl_code_path() == 'AVX2'; "
        + CHOLESKY
    )
    assert pinned == _python(CHOLESKY, MKL_CBWR="AVX2")  # set before the interpreter started
    assert (
        _python(
            "from protorch.app.main import pin_mkl_code_path; print(pin_mkl_code_path())",
            MKL_CBWR="COMPATIBLE",
        )
        == "COMPATIBLE"
    )  # the user's choice is kept


@pytest.mark.slow
@pytest.mark.skipif(
    torch.backends.cpu.get_cpu_capability() != "AVX512",
    reason="this CPU has no AVX-512 path to compare",
)
@pytest.mark.parametrize("name", ["arm_reach", "point_particle"])
def test_an_avx2_and_an_avx512_cpu_give_the_same_run(name):
    code = (
        "import json; from protorch.app.main import pin_mkl_code_path; pin_mkl_code_path(); "
        f"from tests.small_runs import small_run; print(json.dumps(small_run({name!r}, 1)))"
    )
    avx512, avx2 = (
        json.loads(_python(code, ATEN_CPU_CAPABILITY=isa)) for isa in ("avx512", "avx2")
    )
    assert avx512 == avx2  # every metric, and the loops' data sets bit for bit
