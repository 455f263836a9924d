"""The task contract, checked before any work: ``costs (..., O)`` finite and >= 0, ``success (...)``
bool, on the demonstrations and in the loop's batched form; each breach is one line naming the
method, the shapes it was given, what it returned and what it must return."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

from protorch.primitives.promp import resample
from protorch.tasks import (
    PointParticleTask,
    TaskContractError,
    check_task_outputs,
    check_task_protocol,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from examples.reach_around_a_disc import ReachAroundADisc  # noqa: E402


def _demos():
    task = ReachAroundADisc()
    demos, envs = task.demonstrations(3, 2, torch.Generator().manual_seed(0))
    return torch.stack(demos), envs  # (6, 100, 2), (6, 4)


class Summed(ReachAroundADisc):
    def costs(self, traj, env):
        return super().costs(traj, env).sum(-1)


class Negative(ReachAroundADisc):
    def costs(self, traj, env):
        return super().costs(traj, env) - 0.25


class NotFinite(ReachAroundADisc):
    def costs(self, traj, env):
        c = super().costs(traj, env)
        c[..., 1, 2] = float("nan")
        return c


class FloatSuccess(ReachAroundADisc):
    def success(self, traj, env):
        return super().success(traj, env).double()


class OneSuccessPerBatch(ReachAroundADisc):
    def success(self, traj, env):
        return super().success(traj, env).all()


class NoBroadcast(ReachAroundADisc):
    def costs(self, traj, env):
        if traj.ndim != 3:
            raise RuntimeError("expects (n, T, D)\nonly")
        return super().costs(traj, env)


class ListCosts(ReachAroundADisc):
    def costs(self, traj, env):
        return super().costs(traj, env).tolist()


def test_a_task_keeping_its_contract_passes_and_tells_its_objectives():
    traj, envs = _demos()
    assert check_task_outputs(ReachAroundADisc(), traj, envs) == 3
    pp = PointParticleTask()
    demos, penv = pp.demonstrations(2, 2, torch.Generator().manual_seed(0))  # of different lengths
    ptraj = torch.stack(
        [resample(d, 100) for d in demos]
    )  # (4, 100, 2), as the experiments resample them
    assert check_task_outputs(pp, ptraj, penv, dtype=torch.float32) == 3


@pytest.mark.parametrize(
    "cls, message",
    [
        (
            Summed,
            "costs(traj (6, 100, 2), env (6, 4)) returned shape (6,); it must return (6, O) with O "
            ">= 1",
        ),
        (
            Negative,
            "costs(traj (6, 100, 2), env (6, 4)) returned -0.25 at index (0, 0); every cost must "
            "be >= 0",
        ),
        (
            NotFinite,
            "costs(traj (6, 100, 2), env (6, 4)) returned nan at index (1, 2); every cost must be "
            "finite",
        ),
        (ListCosts, "costs(traj (6, 100, 2), env (6, 4)) returned a list; it must return (6, O)"),
        (
            FloatSuccess,
            "success(traj (6, 100, 2), env (6, 4)) returned shape (6,), dtype torch.float64; "
            "it must return (6,) bool",
        ),
        (
            OneSuccessPerBatch,
            "success(traj (6, 100, 2), env (6, 4)) returned shape (), dtype torch.bool; "
            "it must return (6,) bool",
        ),
        (
            NoBroadcast,
            "costs(traj (6, 2, 100, 2), env (6, 1, 4)) raised RuntimeError: expects (n, T, D) only",
        ),
    ],
)
def test_a_breach_is_one_line_naming_the_method_and_both_shapes(cls, message):
    traj, envs = _demos()
    with pytest.raises(TaskContractError) as err:
        check_task_outputs(cls(), traj, envs)
    text = str(err.value)
    assert (
        text.startswith(f"task {__name__}.{cls.__qualname__}: ")
        and message in text
        and "\n" not in text
    )
    assert isinstance(err.value, ValueError) and isinstance(err.value, TypeError)


def test_a_missing_member_is_a_contract_error_too():
    class Half:
        name, num_dof, env_dim = "half", 2, 1

    with pytest.raises(
        TaskContractError, match="lacks sample_envs, costs, success, demonstrations"
    ):
        check_task_protocol(Half())
