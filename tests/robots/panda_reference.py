"""The Panda's numbers that the robot description must not change
(``tests/robots/test_panda_unchanged.py``).

:func:`compute` runs a small deterministic computation on the default Panda with
``collision=skeleton`` (and, for the capsules, ``volume``): forward kinematics, capsule end
points, the objectives, success and the arm-can gap of fixed trajectories, the MuJoCo scene's
masses, inertias, damping, armature and motor limits, and a short MuJoCo rollout under fixed
torques. Only APIs that existed before the robot description are used, so the same function ran
on main at 9e99b1a (before ``protorch.robots.Robot``) and wrote ``data/panda_9e99b1a.json``::

    git checkout 9e99b1a && PYTHONPATH=. python tests/robots/panda_reference.py
    tests/robots/data/panda_9e99b1a.json

The test recomputes it on the current tree and asserts equality (float64 values written with
``repr``: exact)."""

from __future__ import annotations

import json
import math
import sys

import torch

F64 = torch.float64


def _trajectories(task) -> tuple[torch.Tensor, torch.Tensor]:
    """Four fixed joint trajectories ``(4, 50, J)`` around the start and four environments ``(4,
    4)``."""
    q0 = task.start_config(F64)  # (J,)
    t = torch.linspace(0.0, 1.0, 50, dtype=F64)[:, None]  # (T, 1)
    j = torch.arange(q0.shape[0], dtype=F64)[None]  # (1, J)
    trajs = [
        q0 + a * torch.sin(math.pi * t * (1.0 + 0.3 * j) + k) * t
        for k, a in enumerate((0.1, 0.25, 0.4, 0.6))
    ]
    envs = torch.tensor(
        [
            [0.55, 0.0, 0.7, 0.1],
            [0.6, 0.1, 0.7, -0.2],
            [0.52, -0.1, 0.72, 0.2],
            [0.58, 0.05, 0.68, 0.0],
        ],
        dtype=F64,
    )
    return torch.stack(trajs), envs


def compute() -> dict:
    from protorch.tasks.arm.reach import ArmReachTask

    out = {}
    for collision in ("skeleton", "volume"):
        for can_objective in ("ee", "skeleton", "volume"):
            task = ArmReachTask(collision=collision, can_objective=can_objective)
            traj, envs = _trajectories(task)
            key = f"{collision}/{can_objective}"
            out[f"{key}/costs"] = task.costs(traj, envs).flatten().tolist()
            out[f"{key}/success"] = task.success(traj, envs).tolist()
            out[f"{key}/gap"] = task.can_gap(traj, envs).tolist()
            out[f"{key}/margin"] = task.margin
    task = ArmReachTask(collision="skeleton")
    traj, envs = _trajectories(task)
    kin = task.kinematics
    out["frames"] = kin.frames(traj[:, ::10]).flatten().tolist()
    out["ee"] = kin.ee_position(traj[:, ::10]).flatten().tolist()
    out["start"] = list(task.start)
    out["limits"] = [kin.lower.tolist(), kin.upper.tolist(), kin.max_velocity.tolist()]
    out["side"] = task.side(traj, envs).tolist()
    ik_envs = torch.tensor([[0.55, 0.2, 0.7, -0.1], [0.6, -0.2, 0.72, 0.15]], dtype=F64)
    q_ik, err = task.ik_path(task.straight_paths(ik_envs, 50))  # (2, 50, J): the demonstrator's IK
    out["ik/q"] = q_ik.flatten().tolist()
    out["ik/success"] = task.success(q_ik, ik_envs).tolist()
    out["ik/costs"] = task.costs(q_ik, ik_envs).flatten().tolist()
    try:
        import mujoco
        import numpy as np

        from protorch.sim.scene import build_scene, controller_model
    except ImportError:
        return out
    scene = build_scene(ArmReachTask(collision="volume"))
    m = scene.model
    for name in (
        "body_mass",
        "body_ipos",
        "body_inertia",
        "body_iquat",
        "dof_damping",
        "dof_armature",
        "actuator_forcerange",
        "geom_size",
        "geom_pos",
        "jnt_range",
    ):
        out[f"mj/{name}"] = np.asarray(getattr(m, name)).flatten().tolist()
    out["mj/torque_limits"] = scene.torque_limits.tolist()
    data = mujoco.MjData(m)
    data.qpos[scene.qpos_index] = np.asarray(task.start_q)
    data.ctrl[:] = np.linspace(-2.0, 2.0, m.nu)
    for _ in range(200):
        mujoco.mj_step(m, data)
    out["mj/rollout_qpos"] = data.qpos.tolist()
    ctrl = controller_model(ArmReachTask(collision="volume"), mass_scale=1.3)
    out["mj/controller_mass"] = np.asarray(ctrl.body_mass).tolist()
    return out


if __name__ == "__main__":
    with open(sys.argv[1], "w") as f:
        json.dump(compute(), f)
