"""Passing a plan that is surely clear of the can without placing its capsules: lower bounds of
the arm's gap to the can at configurations checked before, carried to new configurations by how
far a joint change can move a point of the arm (:class:`ClearanceMemo`).

The plan check of a policy's class decision (:func:`~protorch.control.arm_choice.rest_blocked`)
places the arm's link capsules at every configuration of a class's plan for the rest of the motion
and bounds their distance to the can: a few hundred tensor operations, most of a decision's
time. From one decision to the next (20 ms) the plan, the arm and the can move little. If every
point of the arm moves by at most ``delta`` between an old configuration ``q'`` and a new one
``q`` and the can's axis by ``delta_can``, the capsules' gap at ``q`` is at least the gap at ``q'``
minus ``delta + delta_can`` (a distance between two sets moves by at most what either moves).
``delta`` is bounded by ``sum_j reach_j |q_j - q'_j|``: joint ``j`` turning by ``dq`` moves a
point at distance ``rho`` from its axis by at most ``rho |dq|``, and ``reach_j`` bounds that
distance for every capsule point after joint ``j`` over all configurations (:func:`point_reach`,
from the chain's fixed maps). A new configuration whose bound from some checked configuration
exceeds the margin (by :data:`SLACK`) is clear, the verdict the full check gives; only where a
configuration is not surely clear does the full check run (and its bounds are kept).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["SLACK", "ClearanceMemo", "point_reach"]

# metres above the margin a carried bound must keep (far above the bounds' round-off, 1e-14)
SLACK = 1e-6


def point_reach(kinematics, plan) -> Tensor:
    """``(J,)`` metres: for each joint, a bound on the distance of every point of ``plan`` (a
    :class:`~protorch.robots.PointPlan` of points on the links after that joint) from the joint's
    axis, over all configurations: the norms of the fixed maps' translations between the joint and
    the point's frame plus the point's norm in that frame (rotations keep norms)."""
    maps = torch.tensor(kinematics._maps, dtype=torch.float64)  # (J + 1, 3, 4) G_0 .. G_J
    shift = maps[:, :, 3].norm(dim=-1).tolist()  # (J + 1,) |t(G_i)|
    size = (
        plan.start.to(torch.float64).norm(dim=-1).tolist()
    )  # (M,) each point in the frame after its joint
    j = len(plan.after)
    # point m follows the joints 0 .. last[m] - 1 (plan.after[k]: the first point joint k does not
    # move)
    last = [sum(1 for k in range(j) if plan.after[k] <= m) for m in range(len(size))]
    reach = [0.0] * j
    for k in range(j):
        for m, n in enumerate(last):
            if (
                n > k
            ):  # joint k moves point m: G_{k+1} Rz ... G_{n-1} Rz start_m from joint k's origin
                reach[k] = max(reach[k], sum(shift[k + 1 : n]) + size[m])
    return torch.tensor(reach, dtype=torch.float64)


class ClearanceMemo:
    """Configurations whose gap to the can was bounded by a full check: ``q (M, J)``, the
    smallest lower bound of their capsules' gaps ``lower (M,)`` and the can's axis ``axis (M, 2)``
    then (the newest :attr:`keep`). :meth:`surely_clear` carries them to new configurations
    (module docstring); :meth:`add` keeps a full check's bounds. One motion's memo
    (:meth:`reset` between motions is not needed for correctness: every bound holds anywhere).
    :attr:`passed` and :attr:`checked` count the plans of each kind."""

    def __init__(self, reach: Tensor, keep: int = 64) -> None:
        self.reach = reach.to(torch.float64)  # (J,)
        self.keep = int(keep)
        self.passed = self.checked = (
            0  # plans passed by the bounds, plans checked in full (over the memo's life)
        )
        self.reset()

    def reset(self) -> None:
        """Forget the configurations (the counts stay)."""
        self.q: Tensor | None = None  # (M, J)
        self.lower: Tensor | None = None  # (M,)
        self.axis: Tensor | None = None  # (M, 2)

    def surely_clear(self, plan: Tensor, env: Tensor, margin) -> bool:
        """Whether every configuration of ``plan (R, P, J)`` keeps more than ``margin`` (a number,
        or ``(R,)``) + :data:`SLACK` from the can of ``env (R, 4)`` by the bounds carried from the
        memo's configurations."""
        if self.q is None:
            return False
        reach = self.reach.to(plan)
        moved = (
            plan[:, :, None, :] - self.q
        ).abs() @ reach  # (R, P, M) how far any capsule point can have moved
        can = (env[:, None, 0:2] - self.axis).norm(dim=-1)  # (R, M) how far the can's axis moved
        bound = (self.lower - moved - can[:, None, :]).amax(
            -1
        )  # (R, P) a lower bound of each gap now
        m = margin[:, None] if isinstance(margin, Tensor) else margin
        clear = bool((bound > m + SLACK).all())
        self.passed += clear
        return clear

    def add(self, plan: Tensor, env: Tensor, lower: Tensor) -> None:
        """Keep the configurations ``plan (R, P, J)`` of a full check at ``env (R, 4)`` with their
        smallest capsule gap's lower bound ``lower (R, P)``."""
        self.checked += 1
        q = plan.reshape(-1, plan.shape[-1])  # (R P, J)
        axis = env[:, None, 0:2].expand(*plan.shape[:2], 2).reshape(-1, 2)  # (R P, 2)
        low = lower.reshape(-1)  # (R P,)
        if self.q is not None:
            q, axis, low = (
                torch.cat([self.q, q]),
                torch.cat([self.axis, axis]),
                torch.cat([self.lower, low]),
            )
        self.q, self.axis, self.lower = q[-self.keep :], axis[-self.keep :], low[-self.keep :]
