"""Small policies and runs for the policy's tests: a two-class arm policy (IK demonstrations on
both sides of cans near the straight line, a nearest-4 map; ~20 s of CPU: tests using it are
marked slow), its moving test's episodes, and a point_particle run's config at a tiny budget."""

from __future__ import annotations

import torch

from protorch import ProMP
from protorch.control.arm import run_arm_episodes
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


def moving_episodes(policy: Policy):
    """The moving test's episodes of ``policy`` (6 random moves of the can and the target, seeds
    1 and 2), with at least one class switch."""
    task = policy.task
    res = run_arm_episodes(
        policy,
        task,
        task.sample_envs(6, torch.Generator().manual_seed(1)),
        generator=torch.Generator().manual_seed(2),
        duration=policy.duration,
        hold=0.3,
        dt=0.02,
        switch_margin=policy.switch_margin,
        switch_clearance=policy.switch_clearance,
    )
    assert int(res.switches.sum()) >= 1
    return res


def point_particle_config(
    max_iter: int, samples: int, demo_envs: int, num_envs: int, test: int, episodes: int
) -> dict:
    """A point_particle run's config (``run_experiment``) at a tiny budget, no baselines."""
    return {
        "name": "point_particle",
        "seed": 0,
        "plot": False,
        "optimizer": {
            "name": "pro",
            "beta": 20.0,
            "max_iter": max_iter,
            "num_samples": samples,
            "relevance_samples": samples,
        },
        "gp": {"backend": "torch", "alpha": 1e-3, "var_floor": 1e-4},
        "task": {"_target_": "protorch.tasks.PointParticleTask", "demo_envs": demo_envs},
        "settings": {
            "loop": {"num_envs": num_envs, "batch_size": num_envs},
            "test": {"num_envs": test},
            "dynamic": {"episodes": episodes},
            "dynamic_paper": {"episodes": episodes},
            "baselines": [],
            "progress": False,
        },
    }
