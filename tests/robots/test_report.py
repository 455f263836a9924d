"""What protorch found or defaulted for a robot, printed in the run's end-of-run summary
(protorch.robots.report, called by protorch.experiments.summary)."""

from __future__ import annotations

import torch

from protorch.experiments.summary import build_summary, format_summary
from protorch.robots.ik import ik_seeds
from protorch.robots.report import robot_found_lines

FOUND = {
    "mjcf": {"file": "/x/arm.xml", "bodies": 8, "geoms": 7, "ignored": {"free bodies": 1}},
    "end_link": "tool0",
    "home": {
        "pose": [0.0, 0.5, 1.0, 0.0, 0.5, 0.0],
        "target": [0.4, 0.0, 0.1],
        "residual": 2.5e-11,
        "seed": "perturbed seed 3 of 8 ([...] rad; the middle failed)",
    },
    "layout": {
        "reach": [0.3, 0.8],
        "height": 0.1,
        "can_box": [[0.5, 0.62], [-0.12, 0.12]],
        "goal_box": [[0.66, 0.74], [-0.24, 0.24]],
        "table": [[0.2, 0.9], [-0.5, 0.5]],
        "can_radius": 0.0375,
        "can_height": 0.23,
    },
    "forearm_link": "forearm",
    "locked": {"finger_joint": 0.03},
    "continuous": {"wrist_3": [-3.14159, 3.14159]},
    "balanced": ["link2", "link3"],
    "implausible": ["hand"],
    "meshes": 14,
    "converted": ["a.obj -> x.stl"],
    "ignored": {"<gazebo>": 8, "<transmission>": 6},
    "max_velocity_default": {"joints": ["j1", "j2"], "value": 2.0},
    "max_torque_default": {"joints": ["j3"], "value": 50.0},
}


def test_every_finding_is_one_line():
    lines = robot_found_lines({"robot": {"name": "my_arm", "found": FOUND}})
    text = "\n".join(lines)
    assert lines[0] == "  robot my_arm: found or defaulted" and len(lines) == 1 + 13
    for part in (
        "converted from MJCF /x/arm.xml: 8 bodies, 7 geoms, ignored free bodies=1",
        "end link tool0",
        "IK residual 2.5e-11 m, seed: perturbed seed 3 of 8",
        "workspace (auto, reach x 0.3..0.8 m at height 0.1 m): can x 0.5..0.62, y -0.12..0.12",
        "locked off-chain joints: finger_joint=0.03",
        "continuous joints limited: wrist_3=[-3.142, 3.142]",
        "inertias balanced (A + B >= C): link2, link3",
        "replaced by the geometry's: hand",
        "meshes: 14 read, 1 converted for MuJoCo",
        "ignored tags: <gazebo> x8, <transmission> x6",
        "velocity limit defaulted to 2 rad/s (none plausible in the file): j1, j2",
        "torque limit defaulted to 50 N m (none plausible in the file): j3",
    ):
        assert part in text, part


def test_the_summary_prints_them_and_the_shipped_robots_print_none():
    metrics = {"robot": {"name": "my_arm", "found": FOUND}}
    summary = build_summary("arm_reach", metrics, run_dir="/r", wall_seconds=1.0)
    text = format_summary("arm_reach", summary)
    assert "  robot my_arm: found or defaulted" in text and "    end link tool0" in text
    assert text.index("found or defaulted") < text.index("status ok")
    for quiet in ({"robot": {"name": "panda"}}, {}, {"robot": {"name": "p", "found": {}}}):
        assert "robot" not in build_summary("arm_reach", quiet, run_dir="/r", wall_seconds=1.0)


def test_ik_seeds_start_at_the_middle_and_stay_in_the_limits():
    lo = torch.tensor([-3.0, -1.0, 0.0], dtype=torch.float64)
    hi = torch.tensor([3.0, 2.0, 0.5], dtype=torch.float64)
    seeds = ik_seeds(lo, hi)  # (9, 3)
    assert seeds.shape == (9, 3) and torch.equal(seeds[0], 0.5 * (lo + hi))
    assert bool(((seeds >= lo) & (seeds <= hi)).all()) and torch.equal(seeds, ik_seeds(lo, hi))
    assert ((seeds[1:] - seeds[0]).abs() <= 0.25 * (hi - lo) + 1e-12).all()
