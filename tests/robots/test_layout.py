"""The measured workspace of an arm (protorch.robots.layout): the can's height from the wrist's
bodies (its capsules), not its frame, so that the wrist passes over the can as the Panda's does;
the working height raised where the hand's bodies reach farther below the end link than the
Panda's, so that they pass as high above the table."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from protorch.robots import load_robot
from protorch.robots.description import Capsule, capsule_segments
from protorch.robots.layout import (
    PANDA_HAND_LOW,
    PANDA_LAYOUT,
    PANDA_WRIST_LOW,
    auto_workspace,
    hand_down_layout,
    hand_drop,
    working_height,
    wrist_low,
)

from .user_arm import user_arm_home, user_arm_urdf


def _user_arm(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text(user_arm_urdf())
    return load_robot({"urdf": str(path), "end_link": "tool0", "home": user_arm_home()})


def test_the_panda_wrist_reference_is_the_shipped_panda_s():
    """PANDA_WRIST_LOW is measured on the shipped Panda (its link 6 capsules at home), so the rule
    gives the Panda's 0.23 m can; a shipped robot's workspace stays the Panda's numbers."""
    panda = load_robot("panda")
    assert wrist_low(panda) == pytest.approx(PANDA_WRIST_LOW, abs=1e-4)
    values, measured = auto_workspace(panda)
    assert measured is None and values == PANDA_LAYOUT and values["can_height"] == 0.23


def test_a_thicker_wrist_gets_a_lower_can(tmp_path):
    """The wrist's lowest body point drops by exactly the radius its capsules gain, and the can's
    height follows it in the Panda's proportion."""
    robot = _user_arm(tmp_path)
    low = wrist_low(robot)
    wrist = robot.capsules["wrist_2_link"]  # the frame the second-to-last joint moves
    thick = {
        **robot.capsules,
        "wrist_2_link": tuple(Capsule(c.link, c.a, c.b, c.radius + 0.02) for c in wrist),
    }
    thicker = dataclasses.replace(robot, capsules=thick)
    assert wrist_low(thicker) == pytest.approx(low - 0.02, abs=1e-9)
    none = dataclasses.replace(
        robot, capsules={k: v for k, v in robot.capsules.items() if k != "wrist_2_link"}
    )
    assert wrist_low(none) is None  # no wrist bodies: the frame's rule stands


@pytest.mark.slow
def test_the_can_clears_the_wrist_as_the_panda_s(tmp_path):
    """A custom arm's auto can stands as far below its wrist's bodies, in proportion, as the
    Panda's 0.23 m can below the Panda's link 6."""
    robot = _user_arm(tmp_path)
    values, measured = auto_workspace(robot)
    low = wrist_low(robot)
    assert measured is values and values["wrist_low"] == round(low, 4)
    assert values["can_height"] == round(0.23 * low / PANDA_WRIST_LOW, 4)


def test_the_panda_hand_reference_gives_the_panda_s_height():
    """PANDA_HAND_LOW is the shipped Panda's hand's lowest point with its end link 0.10 m up, so
    the raised-height rule leaves an arm like the Panda at ``0.10 s_v``."""
    panda = load_robot("panda")
    drop = hand_drop(panda.kinematics(), panda.capsules)
    assert drop == pytest.approx(0.10 - PANDA_HAND_LOW, abs=1e-4)
    assert working_height(1.0, drop) == pytest.approx(0.10, abs=1e-4)
    assert working_height(0.7, None) == pytest.approx(0.07)  # no hand capsules: the frame's rule


def _hand_low(robot, kin, home) -> float:
    """The lowest point (m above the table) of the capsules past the last moving joint."""
    frames = kin.frames(torch.tensor(home, dtype=kin.lower.dtype))
    caps = [c for link in kin.frame_names[-2:] for c in robot.capsules.get(link, ())]
    a, b, r = capsule_segments(frames, kin.frame_names, caps)  # (C, 3), (C, 3), (C,)
    return float((torch.minimum(a[:, 2], b[:, 2]) - r.to(a)).min())


def test_a_longer_hand_works_higher_by_its_length(tmp_path):
    """A tool reaching 0.12 m below the end link (a capsule on it along its z): the hand-down
    home rises until the tool's lowest point stands ``PANDA_HAND_LOW s_v`` above the table, as the
    Panda's hand does; the measured drop is the capsule's length plus its radius."""
    robot = _user_arm(tmp_path)
    kin = robot.kinematics()
    tool = (Capsule("tool0", (0.0, 0.0, 0.0), (0.0, 0.0, 0.10), 0.02),)
    longer = dataclasses.replace(robot, capsules={**robot.capsules, "tool0": tool})
    drop = hand_drop(kin, longer.capsules)
    assert drop == pytest.approx(0.12, abs=1e-9)
    short = hand_down_layout(kin, "the user arm", hand_drop(kin, robot.capsules))
    assert short["height"] == pytest.approx(0.10 * short["scale"], abs=1e-4)
    long = hand_down_layout(kin, "the user arm", drop)
    assert long["height"] == pytest.approx(drop + PANDA_HAND_LOW * long["scale"], abs=1e-4)
    low = _hand_low(longer, kin, long["home"])
    assert low == pytest.approx(PANDA_HAND_LOW * long["scale"], abs=1e-3)
