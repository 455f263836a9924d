"""A small two-class arm policy for the policy's tests: IK demonstrations on both sides of cans
near the straight line, a nearest-4 map (~20 s of CPU: tests using it are marked slow)."""

from __future__ import annotations

import torch

from protorch import ProMP
from protorch.gp import make_env_map
from protorch.loop import demonstration_dataset
from protorch.policy.policy import Policy
from protorch.tasks.arm.reach import LEFT, RIGHT, ArmReachTask

F64 = torch.float64


def two_class_arm_policy(**options) -> Policy:
    """The policy of the two-class arm map; ``options`` are :class:`Policy`'s (over the defaults
    duration 1.5 s, switch margin 0.02, decision interval 0.02 s, switch clearance 0.01 m)."""
    task = ArmReachTask(cost_steps=6)
    g = torch.Generator().manual_seed(0)
    envs = torch.tensor(
        [
            [0.53, 0.02, 0.70, 0.0],
            [0.56, -0.02, 0.74, 0.03],
            [0.59, 0.0, 0.72, -0.03],
            [0.55, 0.05, 0.68, 0.05],
            [0.58, -0.05, 0.71, -0.06],
        ],
        dtype=F64,
    )  # (5, 4)
    n = envs.shape[0]
    dl, el, ll = task.demonstrations(envs, 2, g, sides=torch.full((n,), LEFT), lengths=(30, 30))
    dr, er, lr = task.demonstrations(envs, 2, g, sides=torch.full((n,), RIGHT), lengths=(30, 30))
    promp = ProMP(7, 10, 50)
    ds = demonstration_dataset(
        promp, dl + dr, torch.cat([el, er]), labels=torch.cat([ll, lr]), var_floor=1e-3
    )
    env_map = make_env_map("torch", 30.0, nearest_k=4).fit(ds.env, ds.mean, ds.var, ds.label)
    settings = dict(duration=1.5, switch_margin=0.02, decision_dt=0.02, switch_clearance=0.01)
    return Policy(promp, env_map, task.name, task=task, **{**settings, **options})
