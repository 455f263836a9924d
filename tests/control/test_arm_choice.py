"""The arm's class choice with the plan check: a blocked class is passed over while another is
clear, every class blocked leaves the choice to the scores, and the hysteresis still holds."""

from __future__ import annotations

import torch

from protorch.control.arm_choice import hysteresis_choice


def test_a_blocked_class_is_passed_over_while_another_is_clear():
    scores = torch.tensor([[0.1, 0.1, 0.5], [0.3, 0.3, 0.2]])  # (K=2, E=3): class 0 is cheaper for e = 0, 1
    blocked = torch.tensor([[True, False, False], [False, False, False]])
    assert hysteresis_choice(scores, None, 0.0).tolist() == [0, 0, 1]
    assert hysteresis_choice(scores, None, 0.0, blocked).tolist() == [1, 0, 1]
    # the current class blocked: left whatever the margin
    assert hysteresis_choice(scores, torch.tensor([0, 0, 1]), 10.0, blocked).tolist() == [1, 0, 1]


def test_every_class_blocked_leaves_the_choice_to_the_scores_and_the_hysteresis():
    scores = torch.tensor([[0.10, 0.4], [0.12, 0.2]])  # (K=2, E=2)
    blocked = torch.ones(2, 2, dtype=torch.bool)
    assert hysteresis_choice(scores, None, 0.0, blocked).tolist() == [0, 1]
    # within the margin the current class stays
    assert hysteresis_choice(scores, torch.tensor([1, 0]), 0.05, blocked).tolist() == [1, 1]
    assert hysteresis_choice(scores, torch.tensor([1, 0]), 0.5, blocked).tolist() == [1, 0]
