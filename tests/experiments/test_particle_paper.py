"""The point-particle experiment's authors'-script pieces: the convergence setting, the
moving-test settings and the hole-objective failure analysis."""

from __future__ import annotations

import pytest
import torch

from protorch.experiments.particle_paper import (
    PAPER_SEED,
    convergence_rule,
    hole_failures,
    paper_settings,
)
from protorch.optim.convergence import AuthorsRule
from protorch.tasks import PointParticleTask

F64 = torch.float64
TASK = PointParticleTask(objectives="hole")
ENV = torch.tensor(
    [[1.0, 5.0, 5.0, 5.0, 9.0, 5.0]], dtype=F64
)  # wall x in [4, 6], hole y in (4, 6)


def line(a, b, n=100):
    s = torch.linspace(0, 1, n, dtype=F64)[:, None]
    return torch.as_tensor(a, dtype=F64) + s * (
        torch.as_tensor(b, dtype=F64) - torch.as_tensor(a, dtype=F64)
    )


def test_convergence_setting():
    kw = {"beta": 20.0, "tol": 1e-3, "window": 5}
    assert (
        convergence_rule({**kw, "convergence": "mean"}, "clearance") == kw
    )  # the default adds nothing
    rule = convergence_rule({**kw, "convergence": "authors"}, "clearance")["convergence"]
    assert isinstance(rule, AuthorsRule)
    assert rule.mean_at_most == {0: 0.005, 2: 0.005} and rule.best_at_most == {1: 0.9}
    assert (
        convergence_rule({**kw, "convergence": "authors"}, "hole")["convergence"].best_at_most == {}
    )
    with pytest.raises(ValueError, match="convergence must be one of"):
        convergence_rule({**kw, "convergence": "always"}, "clearance")


def test_paper_settings_refuse_a_training_seed_and_unknown_keys():
    assert paper_settings(None, training_seeds=(0, 1))["seed"] == PAPER_SEED
    with pytest.raises(ValueError, match="training seeds"):
        paper_settings({"seed": 0}, training_seeds=(0, 1))
    with pytest.raises(ValueError, match="speed"):
        paper_settings({"speed": 2.0}, training_seeds=(0, 1))


def test_hole_failures_tells_a_corner_cut_through_the_centre_from_a_miss():
    through_straight = line([1.0, 5.0], [9.0, 5.0])  # along the hole's centre line: no collision
    cut = line(
        [2.0, 1.4], [8.0, 8.6]
    )  # through the centre (5, 5) with slope 1.2: clips two corners
    miss = line([1.0, 8.0], [9.0, 8.0])  # straight through the upper wall
    traj = torch.stack([through_straight, cut, miss])
    env = ENV.expand(3, -1)
    out = hole_failures(TASK, traj, env)
    assert out["means"] == 3 and out["collisions"] == 2
    assert out["collisions_through_centre"] == 1  # the cut passes the centre, the miss does not
    assert out["collisions_at_corners_only"] == 1  # the cut touches the wall only near the corners
