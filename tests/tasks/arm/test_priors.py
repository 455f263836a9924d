"""The arm's grid priors (protorch.tasks.arm.priors): straight priors, kept only when clear
under the task's collision model, and detour priors where the straight one does not hold a side;
every prior kept succeeds and passes on the side its label says."""

from __future__ import annotations

import pytest
import torch

from protorch.primitives.promp import ProMP
from protorch.tasks import ArmReachTask
from protorch.tasks.arm.priors import check_detours, grid_priors
from protorch.tasks.arm.reach import LEFT, RIGHT


@pytest.fixture(scope="module")
def setup():
    return ArmReachTask(collision="volume"), ProMP(
        7, num_basis=10, num_steps=100, dtype=torch.float64
    )


def test_detour_priors_succeed_on_their_side_one_per_node_and_side(setup):
    task, promp = setup
    straight = grid_priors(task, promp, 40, clear=True)
    envs, means, labels, report = grid_priors(task, promp, 40, clear=True, detours=(0.18, 0.24))
    # the straight priors come first, the same as without detours
    n0 = straight[0].shape[0]
    assert (
        n0 == report["clear"]
        and torch.equal(envs[:n0], straight[0])
        and torch.equal(means[:n0], straight[1])
    )
    added = sum(report["detours"].values())
    assert envs.shape[0] == n0 + added and set(report["detours"]) == {"0.18", "0.24"}
    assert added > n0 > 0  # with the volumes most straight paths touch the can: the detours fill in
    traj = promp.trajectory(means)
    assert bool(task.success(traj, envs).all())
    assert torch.equal(task.side(traj, envs), labels)
    pairs = torch.cat([envs, labels[:, None].double()], 1)
    assert (
        torch.unique(pairs, dim=0).shape[0] == pairs.shape[0]
    )  # at most one prior per node and side
    assert int((labels == LEFT).sum()) > 0 and int((labels == RIGHT).sum()) > 0


def test_detour_settings(setup):
    assert (
        check_detours("auto", "volume") == (0.18, 0.24) and check_detours("auto", "skeleton") == ()
    )
    assert check_detours([0.3, 0.2], "skeleton") == (0.2, 0.3) and check_detours([], "volume") == ()
    for bad, match in (
        (0.2, "must be auto or a list"),
        ("near", "must be auto or a list"),
        ([0.2, -1], "> 0"),
        ([True], "> 0"),
        ([float("nan")], "> 0"),
    ):
        with pytest.raises(ValueError, match=match):
            check_detours(bad, "volume")
