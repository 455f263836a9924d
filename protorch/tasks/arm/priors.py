"""The arm's prior knowledge (``experiment=arm_reach``): ProMP means on a grid of environments,
added to the map's data before the loop with the average demonstrated variance.

* **straight priors**: at every grid node the straight end-effector path to the target (by IK,
  one per distinct target: it does not depend on the can), labelled with the side it passes the
  can on. With ``task.prior_clear`` only those whose mean succeeds under the task's collision
  model are kept (with the link volumes most straight paths touch the can: 322 of 2004).
* **detour priors** (``task.prior_detours``, distances in metres): at every grid node and on each
  side, the demonstrator's path without its noise (:func:`~protorch.tasks.arm.demos.detour_paths`:
  through a point that far beside the can) at the first of the distances whose mean succeeds
  under the task's collision model and passes on that side; none where the straight prior already
  holds that side. Their IK uses the compiled chain's Jacobian
  (:meth:`~protorch.robots.ArmKinematics.jacobian_pose`, equal to round-off and several times
  faster). They give the volume-planned map a collision-free mean near every grid node on both
  sides, which the straight priors alone cannot (docs/physics.md).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ...primitives.promp import ProMP
from .demos import detour_paths, follow_path
from .reach import LEFT, RIGHT, ArmReachTask
from .workspace import prior_grid_nodes

__all__ = ["grid_priors", "check_detours"]


def check_detours(value, collision: str) -> tuple[float, ...]:
    """``task.prior_detours``: ``auto`` (0.18 and 0.24 m with ``collision=volume``, none with the
    skeleton), or a list of distances > 0 in metres, tried in increasing order."""
    if value == "auto":
        return (0.18, 0.24) if collision == "volume" else ()
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ValueError(
            f"task.prior_detours must be auto or a list of distances in metres, got {value!r}"
        )
    out = []
    for d in value:
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not float(d) > 0 or d != d:
            raise ValueError(f"task.prior_detours must hold distances > 0 (m), got {d!r}")
        out.append(float(d))
    return tuple(sorted(out))


def _weights(
    task: ArmReachTask, promp: ProMP, paths: Tensor, compiled: bool = False
) -> tuple[Tensor, Tensor]:
    """Joint trajectories following end-effector ``paths (n, T, 3)`` (by IK; ``compiled``: with the
    compiled chain's Jacobian) and their ProMP weights: ``(q (n, T, 7) in the ProMP's dtype and
    device, w (n, N) float64 on the CPU)``."""
    q, _ = follow_path(task, paths, compiled=compiled)  # (n, T, 7)
    q = q.to(promp.basis)
    return q, promp.weights(q).cpu().to(torch.float64)


def grid_priors(
    task: ArmReachTask,
    promp: ProMP,
    n: int,
    over: str = "rectangles",
    clear: bool = False,
    detours: tuple[float, ...] = (),
):
    """``n`` grid environments over ``over``
    (:func:`~protorch.tasks.arm.workspace.prior_grid_nodes`)
    with their straight priors (with ``clear`` only those that succeed) and their detour priors
    (module docstring): ``(envs (P, 4), weight means (P, N), labels (P,), report)``; the report
    holds the grid's counts, ``clear`` (straight priors kept, with ``clear``) and ``detours`` (per
    distance, the detour priors kept)."""
    if n == 0:
        return (
            torch.zeros(0, 4, dtype=torch.float64),
            torch.zeros(0, promp.num_weights, dtype=torch.float64),
            torch.zeros(0, dtype=torch.long),
            {"over": over, "kept": 0},
        )
    grid, report = prior_grid_nodes(task, n, over, promp.num_steps)  # (n, 4)
    goals, inverse = torch.unique(grid[:, 2:], dim=0, return_inverse=True)  # (G, 2), (n,)
    any_can = grid[:1, :2].expand(goals.shape[0], 2)  # the straight path does not depend on the can
    q, w = _weights(
        task, promp, task.straight_paths(torch.cat([any_can, goals], 1), promp.num_steps)
    )  # (G, ...)
    labels = task.side(
        q[inverse.to(q.device)], grid.to(q)
    ).cpu()  # (n,) which side the straight path passes
    w = w[inverse]  # (n, N)
    keep = torch.ones(grid.shape[0], dtype=torch.bool)
    if (
        clear
    ):  # a prior that hits the can under the task's own check teaches the map a colliding mean
        keep = task.success(promp.trajectory(w.to(promp.basis)), grid.to(promp.basis)).cpu()  # (n,)
        report = report | {"clear": int(keep.sum())}
    envs, means, labs = [grid[keep]], [w[keep]], [labels[keep]]
    kept = {str(d): 0 for d in detours}  # the detour priors kept at each distance
    for side in (LEFT, RIGHT):
        todo = torch.nonzero(~(keep & (labels == side))).reshape(
            -1
        )  # the nodes without a prior on this side yet
        for d in detours:
            if todo.numel() == 0:
                break
            paths = detour_paths(task, grid[todo], side, d, promp.num_steps)  # (m, T, 3)
            _, wd = _weights(
                task, promp, paths, compiled=True
            )  # (m, N) (the straight priors keep the chain's IK)
            env = grid[todo].to(promp.basis)
            td = promp.trajectory(wd.to(promp.basis))  # (m, T, 7)
            ok = (task.success(td, env) & (task.side(td, env) == side)).cpu()  # (m,)
            envs.append(grid[todo[ok]])
            means.append(wd[ok])
            labs.append(torch.full((int(ok.sum()),), side, dtype=torch.long))
            kept[str(d)] += int(ok.sum())
            todo = todo[~ok]
    if detours:
        report = report | {"detours": kept}
    return torch.cat(envs), torch.cat(means), torch.cat(labs), report
