"""A trained run as a plain torch module, and label-aware inference.

:class:`EnvToProMP` wraps a ProMP and an environment map: environments ``(B, E)`` -> weight
Gaussians. :func:`label_aware_mean` picks, per environment, the class (homotopy label) whose
predicted mean trajectory has the lowest summed cost (the paper's, and the online choice's at the
start of a motion); with ``check=True`` (the held-out tests) a class whose mean passes the task's
own check (``task.success``: for the arm, clear of the can and the table under its collision
model) comes first: a robot checks its plan before it moves.
"""

from __future__ import annotations

import copy

import torch
from torch import Tensor, nn

__all__ = ["EnvToProMP", "label_aware_mean", "class_score", "INFEASIBLE"]

INFEASIBLE = (
    1e6  # added to the score of a mean that fails the task's check (summed costs are O(1)-O(10))
)


class EnvToProMP(nn.Module):
    """A trained run: environments ``(B, d)`` -> ProMP weight Gaussians ``(mu (B, N), var (B, N))``.

    ``model.promp.trajectory(mu)`` gives the mean trajectories ``(B, T, D)``;
    ``model.task_name`` names the task the run solved.
    """

    def __init__(self, promp, env_map, task_name: str = "") -> None:
        super().__init__()
        if promp.num_weights != env_map.num_weights:
            raise ValueError(
                f"the ProMP has {promp.num_weights} weights but the environment map predicts "
                f"{env_map.num_weights}"
            )
        self.promp = promp
        self.env_map = env_map
        self.task_name = str(task_name)

    @property
    def env_dim(self) -> int:
        return self.env_map.env_dim

    def forward(self, env: Tensor, labels=None) -> tuple[Tensor, Tensor]:
        return self.env_map.predict(env, labels)

    def mean_trajectory(self, env: Tensor, labels=None) -> Tensor:
        """``(B, d)`` -> mean trajectories ``(B, T, D)``."""
        return self.promp.trajectory(self.env_map.predict_mean(env, labels))

    def extra_repr(self) -> str:
        return f"task_name={self.task_name!r}, env_dim={self.env_dim}"


def class_score(promp, task, dtype=None, check: bool = False):
    """The label-aware inference's score of means ``(P, N)`` at environments ``(P, E)``: the summed
    task objectives of the mean trajectory; with ``check``, plus :data:`INFEASIBLE` where the
    trajectory fails ``task.success`` (so a class whose mean passes the check always beats one
    whose mean does not; between two of a kind the lower cost wins): ``(P,)``."""

    def score(mu: Tensor, e: Tensor) -> Tensor:
        traj = promp.trajectory(mu if dtype is None else mu.to(dtype))  # (P, T, D)
        e = e.to(traj.dtype)
        cost = task.costs(traj, e).sum(-1)  # (P,)
        if not check:
            return cost
        return cost + INFEASIBLE * (~task.success(traj, e)).to(cost.dtype)

    return score


def label_aware_mean(
    env_map, promp, task, env: torch.Tensor, dtype=torch.float32, check: bool = False
):
    """The label-aware inference (module docstring): every label's predicted mean scored by
    :func:`class_score` (``check``: the task's check first), the best kept. Returns the
    :class:`~protorch.gp.BestPrediction` (``mean (Q, N)``, ``label (Q,)``, ``scores (Q, K)``)."""
    p = copy.deepcopy(promp).to(dtype) if promp.basis.dtype != dtype else promp
    return env_map.predict_best(env, class_score(p, task, dtype, check), need_var=False)
