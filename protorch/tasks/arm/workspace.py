"""Where the arm-reach task's environments come from (:class:`protorch.tasks.ArmReachTask`):
the two regions, their validity rules, the uniform sampler and the regular prior grid.

Regions (``region=`` / ``over=``):

* ``"rectangles"`` (the default): can in ``task.can_box``, target in ``task.goal_box``
  (``[0.50, 0.62] x [-0.12, 0.12]`` and ``[0.66, 0.74] x [-0.24, 0.24]``); valid when can, target
  and start are ``min_separation`` apart. Every target there lies inside ``task.reach``.
* ``"table"``: can and target each anywhere on the table top ``task.table``
  (``[0.2, 0.9] x [-0.5, 0.5]``), the reading of "environments spread over the table" of the
  paper's arm experiment (its text gives no numeric ranges). Valid when, besides the separation,
  the target is within the hand-down Panda's reach (horizontal distance from the base's axis in
  ``task.reach``, default ``[0.30, 0.80]``: on a 2 cm lattice of table targets the IK follows the
  straight path from the start, every step within 2 cm, inside the joint limits and above the
  table, for every target with ``0.28 <= r <= 0.82`` and for none with ``r <= 0.272`` or
  ``r >= 0.830``) and the can stands clear of the arm's start posture (its skeleton more than
  ``can_radius + margin`` from the can's axis).

:func:`prior_grid_nodes` puts a regular ``k^4`` grid over a region, keeps its valid nodes and, for
``"table"``, also drops every node whose straight-line prior the IK cannot follow (none, by the
measurement above; counted, never silent); ``n`` evenly spaced nodes (lexicographic order) of the
smallest such grid with at least ``n`` are kept, with a report of every count.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "REGIONS",
    "check_region",
    "check_box",
    "check_workspace",
    "check_reach",
    "region_bounds",
    "valid_envs",
    "sample_envs",
    "prior_grid_nodes",
    "straight_prior_ok",
    "goal_in_reach",
    "can_clear_of_start",
    "separated",
]

REGIONS = ("rectangles", "table")


def check_region(region: str, name: str = "region") -> str:
    """``region`` if it is one of :data:`REGIONS`, else a ``ValueError`` naming the setting."""
    if region not in REGIONS:
        raise ValueError(f"{name} must be one of {', '.join(REGIONS)}, got {region!r}")
    return region


def check_box(name: str, box) -> tuple[tuple[float, float], tuple[float, float]]:
    """``box`` as ``((x_min, x_max), (y_min, y_max))`` floats, ``x_min < x_max``, ``y_min <
    y_max``."""
    try:
        (x0, x1), (y0, y1) = box
        x0, x1, y0, y1 = float(x0), float(x1), float(y0), float(y1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be ((x_min, x_max), (y_min, y_max)), got {box!r}") from None
    if not (x0 < x1 and y0 < y1) or not all(map(math.isfinite, (x0, x1, y0, y1))):
        raise ValueError(f"{name} must have x_min < x_max and y_min < y_max, got {box!r}")
    return (x0, x1), (y0, y1)


def check_workspace(task) -> None:
    """Check and normalise (in place) a task's ``can_box``, ``goal_box``, ``table``, ``region``
    and ``reach``: boxes as float pairs on the table, ``0 <= r_min < r_max``."""
    task.can_box, task.goal_box = (
        check_box("can_box", task.can_box),
        check_box("goal_box", task.goal_box),
    )
    task.table = check_box("table", task.table)
    check_region(task.region)
    try:
        task.reach = (float(task.reach[0]), float(task.reach[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"reach must be (r_min, r_max), got {task.reach!r}") from None
    if not (0 <= task.reach[0] < task.reach[1] < math.inf):
        raise ValueError(
            f"reach must be (r_min, r_max) with 0 <= r_min < r_max < inf, got {task.reach!r}"
        )
    for name, box in (("can_box", task.can_box), ("goal_box", task.goal_box)):
        if not all(t[0] <= b[0] and b[1] <= t[1] for b, t in zip(box, task.table)):
            raise ValueError(f"{name} {box} must lie on the table {task.table}")


def check_reach(task, prior_grid: str = "rectangles", iters: int = 150) -> None:
    """Refuse a workspace out of the arm's reach, before any work: the hand-down inverse
    kinematics (from the start configuration, the hand keeping its start orientation, ``iters``
    damped-least-squares steps) must bring the end effector within ``goal_tol`` of every corner
    of ``task.goal_box`` at the start's height, the arm above the table (and, where the task's
    region or ``prior_grid`` is the table, of the farthest target of ``task.reach`` straight
    ahead). A ``ValueError`` naming the settings and the first target missed."""
    (x0, x1), (y0, y1) = task.goal_box
    goals = [(x0, y0), (x0, y1), (x1, y0), (x1, y1)]
    if "table" in (task.region, prior_grid):
        goals.append((min(task.reach[1], task.table[0][1]), 0.0))
    kin = task.kinematics
    kw = dict(dtype=kin.lower.dtype, device=kin.lower.device)
    g = torch.tensor([(x, y, task.ee_height) for x, y in goals], **kw)  # (G, 3)
    rest = task.start_config(**kw)  # (J,)
    rot = kin.ee_pose(rest)[:3, :3].expand(len(goals), 3, 3)
    q, err = kin.inverse(
        g, rest.expand(len(goals), -1), rotation=rot, rest=rest, iters=iters
    )  # (G, J), (G,)
    ok = ((err <= task.goal_tol) & (kin.link_positions(q)[..., 1:, 2] >= 0).all(-1)).cpu()  # (G,)
    if not bool(ok.all()):
        miss = goals[int((~ok).nonzero()[0])]
        what = "task.goal_box" if int((~ok).nonzero()[0]) < 4 else "task.reach"
        raise ValueError(
            f"{what}: the target ({miss[0]:.3f}, {miss[1]:.3f}) at the start's height is out of "
            "the "
            f"{task.robot.name} arm's reach (the hand-down inverse kinematics from robot.home "
            "misses "
            "it); move task.goal_box / task.can_box (or task.reach) nearer the base, or choose "
            "another "
            "robot.home"
        )


def region_bounds(task, region: str) -> tuple[Tensor, Tensor]:
    """``(lo, hi)``, each ``(4,)`` float64: the box ``(can_x, can_y, goal_x, goal_y)``
    of a region."""
    check_region(region)
    can, goal = (
        (task.can_box, task.goal_box) if region == "rectangles" else (task.table, task.table)
    )
    lo = torch.tensor([can[0][0], can[1][0], goal[0][0], goal[1][0]], dtype=torch.float64)
    hi = torch.tensor([can[0][1], can[1][1], goal[0][1], goal[1][1]], dtype=torch.float64)
    return lo, hi


def separated(task, env: Tensor) -> Tensor:
    """Can, target and start at least ``min_separation`` apart: ``(...)`` bool."""
    s = env.new_tensor(task.start[:2])
    sep = task.min_separation
    return (
        ((env[..., :2] - env[..., 2:]).norm(dim=-1) >= sep)
        & ((env[..., :2] - s).norm(dim=-1) >= sep)
        & ((env[..., 2:] - s).norm(dim=-1) >= sep)
    )


def goal_in_reach(task, env: Tensor) -> Tensor:
    """The target's horizontal distance from the base's axis within ``task.reach``:
    ``(...)`` bool."""
    r = env[..., 2:4].norm(dim=-1)
    return (r >= task.reach[0]) & (r <= task.reach[1])


def can_clear_of_start(task, env: Tensor) -> Tensor:
    """The arm's start posture (under ``task.collision``) more than ``margin`` from the can's
    surface: ``(...)`` bool."""
    frames = task.kinematics.frames(
        task.start_config(env.dtype, task.kinematics.lower.device)
    )  # (F, 4, 4)
    return task.frames_gap(frames.to(env.device)[None], env) > task.margin  # (...)


def valid_envs(task, env: Tensor, region: str) -> Tensor:
    """Whether environments ``(..., 4)`` are valid in ``region`` (module docstring): ``(...)``
    bool."""
    ok = separated(task, env)
    if check_region(region) == "table":
        ok = ok & goal_in_reach(task, env) & can_clear_of_start(task, env)
    return ok


def sample_envs(task, n: int, generator, region: str, dtype=torch.float64, device=None) -> Tensor:
    """``n`` environments ``(n, 4)`` uniform over ``region``, redrawn until valid (float64 on the
    CPU, then moved)."""
    if isinstance(n, bool) or int(n) != n or int(n) < 0:
        raise ValueError(f"n must be an int >= 0, got {n!r}")
    n = int(n)
    out = torch.empty(0, 4, dtype=torch.float64)
    lo, hi = region_bounds(task, region)
    for _ in range(1000):
        if out.shape[0] >= n:
            break
        e = lo + (hi - lo) * torch.rand(
            max(2 * (n - out.shape[0]), 16), 4, generator=generator, dtype=torch.float64
        )
        out = torch.cat([out, e[valid_envs(task, e, region)]])
    else:
        raise RuntimeError(f"the {region} region leaves (almost) no room for valid environments")
    return out[:n].to(dtype=dtype, device=device)


def straight_prior_ok(task, goals: Tensor, num_steps: int = 100) -> Tensor:
    """Whether the IK follows the straight end-effector path from the start to each target
    ``goals (G, 2)`` (every step within ``goal_tol``, joint limits, above the table): ``(G,)``
    bool."""
    env = torch.cat(
        [goals.new_tensor(task.start[:2]).expand_as(goals), goals], -1
    )  # the can plays no part
    q, err = task.ik_path(task.straight_paths(env, num_steps))  # (G, T, 7), (G, T)
    above = (task.kinematics.link_positions(q)[..., 1:, 2] >= 0).flatten(1).all(-1)
    ok = (err.amax(-1) <= task.goal_tol) & task.kinematics.within_limits(q).all(-1) & above
    return ok.cpu()


def _first_failure(task, grid: Tensor, region: str) -> dict:
    """How many grid nodes each rule removes, in order (a node counts under its first failure)."""
    sep = separated(task, grid)
    counts = {"too_close": int((~sep).sum())}
    if region == "table":
        reach = goal_in_reach(task, grid)
        counts["goal_out_of_reach"] = int((sep & ~reach).sum())
        counts["can_on_start_posture"] = int((sep & reach & ~can_clear_of_start(task, grid)).sum())
    return counts


def prior_grid_nodes(
    task, n: int = 2004, over: str = "rectangles", num_steps: int = 100
) -> tuple[Tensor, dict]:
    """``n`` environments on a regular grid over the region ``over`` and a report of the counts:
    ``(grid (n, 4), {"over", "per_axis", "nodes", <removed by each rule>, "ik_failed", "valid",
    "kept"})`` (module docstring)."""
    if isinstance(n, bool) or int(n) != n or int(n) < 1:
        raise ValueError(f"n must be an int >= 1, got {n!r}")
    check_region(over, "prior_grid")
    lo, hi = region_bounds(task, over)
    for k in range(2, 64):
        full = torch.cartesian_prod(
            *[torch.linspace(float(a), float(b), k, dtype=torch.float64) for a, b in zip(lo, hi)]
        )  # (k^4, 4)
        ok = valid_envs(task, full, over)
        if int(ok.sum()) < n:
            continue
        grid, ik_failed = full[ok], 0
        if (
            over == "table"
        ):  # the straight-line priors must be reachable: drop (and count) those that are not
            goals, inverse = torch.unique(grid[:, 2:], dim=0, return_inverse=True)
            follow = straight_prior_ok(task, goals, num_steps)[inverse]
            ik_failed = int((~follow).sum())
            grid = grid[follow]
            if grid.shape[0] < n:
                continue
        idx = torch.linspace(0, grid.shape[0] - 1, int(n), dtype=torch.float64).round().long()
        report = {
            "over": over,
            "per_axis": k,
            "nodes": int(full.shape[0]),
            **_first_failure(task, full, over),
            "ik_failed": ik_failed,
            "valid": int(grid.shape[0]),
            "kept": int(n),
        }
        return grid[idx], report
    raise RuntimeError(f"no grid up to 63^4 has {n} valid environments over the {over} region")
