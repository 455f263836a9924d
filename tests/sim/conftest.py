"""Shared pieces of the physics tests: MuJoCo (skipped, saying so, where it is not installed), the
task, and a straight reach as a ProMP."""

from __future__ import annotations

import pytest
import torch

from protorch.primitives.promp import ProMP
from protorch.tasks import ArmReachTask

pytest.importorskip(
    "mujoco",
    minversion="4.0",
    reason="the physics extra is not installed: pip install protorch[physics]",
)


@pytest.fixture(scope="module")
def task():
    return ArmReachTask(collision="volume")


@pytest.fixture(scope="module")
def reach(task):
    """A ProMP and the weights of the straight reach from the start to the target (0.70, -0.10)."""
    promp = ProMP(7, num_basis=10, num_steps=100, dtype=torch.float64)
    env = torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64)
    q, err = task.ik_path(task.straight_paths(env, 100))
    assert float(err.max()) < 2e-3
    return promp, promp.weights(q)  # (1, N)
