"""Small runs for the viewer's tests: a point-particle GP on 30 x 3 synthetic demonstrations
(checkpoint + config.yaml, well under a second) and a synthetic arm map (a few seconds of IK);
and headless Chromium for the browser tests (``browser``: skipped, with the reason, where no
``chromium`` is installed or playwright is missing; playwright drives the system Chromium through
``executable_path``, ``playwright install`` is never needed)."""

from __future__ import annotations

import shutil

import pytest
import torch

from protorch import ProMP, demonstration_dataset, save_model
from protorch.data.dataset import TrajectoryDataset
from protorch.tasks import ArmReachTask, PointParticleTask


def make_particle_run(run_dir, *, objectives: str = "clearance"):
    task = PointParticleTask(objectives=objectives)
    promp = ProMP(2, num_basis=10, num_steps=100)
    demos, envs = task.demonstrations(30, 3, torch.Generator().manual_seed(0))
    ds = demonstration_dataset(promp, demos, envs, task_name=task.name, var_floor=1e-4)
    save_model(run_dir, ds, backend="torch", alpha=1e-3)
    (run_dir / "config.yaml").write_text(
        f"name: point_particle\ntask:\n  objectives: {objectives}\n  demo_envs: 30\n"
    )
    return run_dir


@pytest.fixture(scope="session")
def particle_run_dir(tmp_path_factory):
    return make_particle_run(tmp_path_factory.mktemp("pp"))


@pytest.fixture(scope="session")
def particle_run_factory():
    """``make(run_dir)``: write another small point-particle run into ``run_dir``."""
    return make_particle_run


@pytest.fixture(scope="session")
def arm_run_dir(tmp_path_factory):
    """A synthetic arm run: 200 random environments, each with the weights of the straight path
    (by IK) to the nearest of 4 grid targets plus noise, side labels at random (nearest_k 30)."""
    out = tmp_path_factory.mktemp("arm")
    task, promp = ArmReachTask(), ProMP(7, num_basis=10, num_steps=100)
    gen = torch.Generator().manual_seed(0)
    goals = task.prior_grid(4)  # (4, 4)
    q, _ = task.ik_path(task.straight_paths(goals, promp.num_steps))  # (4, T, 7)
    w = promp.weights(q)  # (4, N)
    env = task.sample_envs(200, gen)  # (M, 4)
    mean = w[torch.cdist(env[:, 2:], goals[:, 2:]).argmin(1)] + 0.01 * torch.randn(
        200, w.shape[1], generator=gen, dtype=torch.float64
    )
    ds = TrajectoryDataset(promp, 4, task_name=task.name)
    ds.append(
        env,
        mean,
        torch.full_like(mean, 1e-4),
        label=torch.randint(0, 2, (200,), generator=gen),
        origin="prior",
        converged=True,
    )
    save_model(out, ds, backend="torch", alpha=30.0, nearest_k=30)
    return out


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
]


@pytest.fixture(scope="session")
def browser():
    """Headless Chromium (software WebGL), one per test session."""
    pytest.importorskip("viser", reason="viser is not installed (pip install -e '.[view]')")
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')"
    )
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (apt-get install -y chromium)")
    with sync_api.sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()
