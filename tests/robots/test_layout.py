"""The measured workspace of an arm (protorch.robots.layout): the can's height from the wrist's
bodies (its capsules), not its frame, so that the wrist passes over the can as the Panda's does."""

from __future__ import annotations

import dataclasses

import pytest

from protorch.robots import load_robot
from protorch.robots.description import Capsule
from protorch.robots.layout import PANDA_LAYOUT, PANDA_WRIST_LOW, auto_workspace, wrist_low

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
