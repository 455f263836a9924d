"""Every core module on every available device and in float32 / float64 (CUDA runs where lent)."""

from __future__ import annotations

import pytest
import torch

from protorch import PRO, RWPO, RWR, ProMP
from protorch.optim import CEM, CMAES
from protorch.tasks import WindowTask

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.slow
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("cls", [PRO, RWR, RWPO, CEM, CMAES])
def test_window_task_improves_on_device(device, dtype, cls):
    task = WindowTask()
    demos = [
        d.to(device=device, dtype=dtype)
        for d in task.demonstrations(5, generator=torch.Generator().manual_seed(0))
    ]
    promp = ProMP(2, 10, 100, dtype=dtype, device=device).fit(demos)
    assert promp.basis.device.type == device and promp.basis.dtype == dtype
    mean = torch.stack([promp.mean, promp.mean])  # two problems at once
    var = torch.stack([promp.var, promp.var])
    extra = (
        dict(
            num_objectives=3,
            num_basis=10,
            relevance_iters=3,
            theta_samples=16,
            trajectory_samples=8,
        )
        if cls is RWPO
        else {}
    )
    if cls not in (CEM, CMAES):  # rank-based: no beta
        extra["beta"] = 20.0
    opt = cls(mean, var, num_samples=64, max_iter=40, seed=0, **extra)
    res = opt.minimize(lambda w: task.costs(promp.trajectory(w)))
    assert res.mean.device.type == device and res.mean.dtype == dtype
    assert torch.isfinite(res.mean).all() and torch.isfinite(res.var).all() and (res.var >= 0).all()
    before = task.costs(promp.mean_trajectory()).sum()
    after = task.costs(promp.trajectory(res.mean)).sum(-1)  # (2,)
    assert (after < before).all()
