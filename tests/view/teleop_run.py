"""A small teleop_window run for the page's tests: the maps of careful demonstrations at 10 walls
(no loop; well under a second) and the config.yaml the app writes."""

from __future__ import annotations

import torch
import yaml

from protorch.control.teleop_guide import variance_map
from protorch.experiments.teleop_window import MAP_FILE, VAR_MAP_FILE
from protorch.gp import make_env_map
from protorch.loop import demonstration_dataset
from protorch.primitives.promp import ProMP
from protorch.tasks import TeleopWindowTask
from protorch.tasks.teleop_operators import careful_demonstrations

GUIDE = {
    "position_gain": 100.0,
    "position_max": 5000.0,
    "rotation_gain": 1.0,
    "rotation_max": 100.0,
}


def make_teleop_run(run_dir):
    task = TeleopWindowTask()
    trajs, envs = careful_demonstrations(task, 10, 3, torch.Generator().manual_seed(0))
    promp = ProMP(7, 10, 100)
    ds = demonstration_dataset(
        promp, trajs, envs, labels=task.label(torch.stack(trajs), envs), var_floor=1e-6
    )
    factory = lambda: make_env_map("torch", alpha=3.0)  # noqa: E731
    env_map = factory().fit(ds.env, ds.mean, ds.var, ds.label)
    env_map.save(run_dir / MAP_FILE)
    variance_map(factory, env_map).save(run_dir / VAR_MAP_FILE)
    cfg = {
        "name": "teleop_window",
        "task": {"_target_": "protorch.tasks.TeleopWindowTask"},
        "settings": {
            "guide": GUIDE,
            "promp": {"num_basis": 10, "num_steps": 100},
            "teleop": {"wall_seed": 0},
        },
    }
    (run_dir / "config.yaml").write_text(yaml.safe_dump(cfg))
    return run_dir
