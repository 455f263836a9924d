"""The arm descriptions of pybullet's ``pybullet_data`` read unedited (docs/your_own_robot.md):
what protorch finds or defaults for each (end link, home, workspace, locked joints, inertias,
converted meshes), the time it takes, and a picture of each arm in its MuJoCo scene, its own
meshes drawn, at home and reaching the target's box's far corner (``--png PATH``).

    pip install "protorch[arms]"        # pybullet, for its pybullet_data folder
    MUJOCO_GL=egl python benchmarks/pybullet_arms.py --png docs/img/pybullet_arms_frames.png
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from _timing import Stopwatch

ARMS = (
    ("xArm 6", "xarm/xarm6_robot.urdf", None),
    ("KUKA iiwa", "kuka_iiwa/model.urdf", None),
    ("Panda", "franka_panda/panda.urdf", "panda_grasptarget"),
)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", default=None, help="write the frames of the three arms here")
    parser.add_argument(
        "--inertia",
        action="store_true",
        help="the joint-space inertia at home of pybullet's Panda: "
        "the file's inertials, repaired, and the shipped Panda's",
    )
    args = parser.parse_args(argv)
    if args.inertia:
        return joint_inertia()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    import numpy as np
    import pybullet_data
    import torch

    from protorch.robots import load_robot
    from protorch.sim.render import render_frames, write_strip
    from protorch.sim.scene import build_scene
    from protorch.tasks import ArmReachTask

    torch.set_num_threads(1)
    frames, titles = [], []
    for label, rel, end in ARMS:
        with Stopwatch() as sw:
            robot = load_robot({"urdf": f"{pybullet_data.getDataPath()}/{rel}", "end_link": end})
            task = ArmReachTask(robot=robot, collision="volume")
        seconds = sw.wall
        found = {k: v for k, v in robot.found.items() if k not in ("layout", "converted")}
        found["converted"] = len(robot.found.get("converted", []))
        print(
            json.dumps(
                {
                    "arm": label,
                    "dof": robot.num_joints,
                    "end_link": robot.end_link,
                    "seconds": round(seconds, 1),
                    "can_box": task.can_box,
                    "goal_box": task.goal_box,
                    "table": task.table,
                    "can": [task.can_radius, task.can_height],
                    "start": [round(v, 4) for v in task.start],
                    "capsules": len(robot.capsule_list()),
                    "found": found,
                }
            )
        )
        if args.png:
            scene = build_scene(task)
            (_, x1), (_, y1) = task.goal_box
            can = np.array([[sum(task.can_box[0]) / 2, 0.0]] * 2)
            goal = np.array([[x1, y1], [x1, y1]])
            env = torch.tensor([[can[0, 0], can[0, 1], x1, y1]], dtype=torch.float64)
            q_goal = task.ik_path(task.straight_paths(env, 20))[0][0, -1].numpy()
            q = np.stack([np.array(robot.home), q_goal])
            frames += render_frames(scene, q, can, goal)
            titles += [f"{label}: home", f"{label}: target corner"]
    if args.png:
        write_strip(
            args.png, frames, titles, "pybullet_data's arms, unedited, in protorch's MuJoCo scene"
        )
        print(f"wrote {args.png}")


def joint_inertia() -> None:
    """The diagonal of MuJoCo's joint-space inertia ``M(q)`` at home (the controller's model) of
    pybullet's Panda with its file's inertials on the chain, repaired, and of the shipped Panda."""
    import dataclasses
    import re
    import xml.etree.ElementTree as ET

    import mujoco
    import numpy as np
    import pybullet_data

    from protorch.robots import load_robot
    from protorch.robots.loader import urdf_inertials
    from protorch.sim.scene import controller_model
    from protorch.tasks import ArmReachTask

    def diagonal(robot):
        model = controller_model(ArmReachTask(robot=robot, collision="volume"))
        data = mujoco.MjData(model)
        data.qpos[:] = robot.home
        mujoco.mj_forward(model, data)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        return np.round(np.diag(full), 4).tolist()

    path = f"{pybullet_data.getDataPath()}/franka_panda/panda.urdf"
    fixed = load_robot({"urdf": path, "end_link": "panda_grasptarget"})
    text = re.sub(r"^\s*<\?xml[^>]*\?>", "", Path(path).read_text())
    as_is = dataclasses.replace(
        fixed,
        inertials={k: v for k, v in urdf_inertials(ET.fromstring(text)).items() if v.mass > 0},
    )
    for label, robot in (
        ("the file's inertials", as_is),
        ("repaired", fixed),
        ("shipped Panda", load_robot("panda")),
    ):
        print(
            f"{label}: M(home) diagonal {diagonal(robot)} kg m^2, effort {list(robot.max_torque)} "
            "N m"
        )


if __name__ == "__main__":
    main()
