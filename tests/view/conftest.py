"""A small point-particle run for the viewer's tests: the GP on 30 x 3 synthetic demonstrations,
saved as a trained run is (checkpoint + config.yaml), in well under a second."""

from __future__ import annotations

import pytest
import torch

from protorch import ProMP, demonstration_dataset, save_model
from protorch.tasks import PointParticleTask


def make_particle_run(run_dir, *, objectives: str = "clearance"):
    task = PointParticleTask(objectives=objectives)
    promp = ProMP(2, num_basis=10, num_steps=100)
    demos, envs = task.demonstrations(30, 3, torch.Generator().manual_seed(0))
    ds = demonstration_dataset(promp, demos, envs, task_name=task.name, var_floor=1e-4)
    save_model(run_dir, ds, backend="torch", alpha=1e-3)
    (run_dir / "config.yaml").write_text(f"name: point_particle\ntask:\n  objectives: {objectives}\n  demo_envs: 30\n")
    return run_dir


@pytest.fixture(scope="session")
def particle_run_dir(tmp_path_factory):
    return make_particle_run(tmp_path_factory.mktemp("pp"))


@pytest.fixture(scope="session")
def particle_run_factory():
    """``make(run_dir)``: write another small point-particle run into ``run_dir``."""
    return make_particle_run
