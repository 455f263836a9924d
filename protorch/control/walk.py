"""The bounded random walk of the point particle's hole and goal during an online episode
(:func:`~protorch.control.particle.run_episodes`).

Independent Gaussian steps on ``hole_y``, ``goal_x``, ``goal_y``, reflected into the sampler's
ranges (``hole_y in [1, 9]``, ``goal_x in [wall_x + 1.5, 10]``, ``goal_y in [0, 10]``); the start
and ``wall_x`` stay fixed. Specific to the point-particle environment layout.
"""

from __future__ import annotations

import numbers
from typing import Sequence

import torch
from torch import Tensor

from ..checks import check_number
from .episodes import check_episode_envs

__all__ = ["WALKED", "random_walk_envs", "walk_bounds"]

# point-particle environment layout (6-D): start_x, start_y, wall_x, hole_y, goal_x, goal_y
WALKED = ("hole_y", "goal_x", "goal_y")  # the coordinates the random walk moves
_COLS6 = {"start_x": 0, "start_y": 1, "wall_x": 2, "hole_y": 3, "goal_x": 4, "goal_y": 5}
_GOAL_MARGIN = 1.5  # the sampler's goal_x >= wall_x + 1.5
_BOUND_TOL = 1e-9


def _walk_columns(task, d: int) -> tuple[int, int, int, int]:
    """Columns of ``wall_x, hole_y, goal_x, goal_y`` in a ``d``-D environment (6-D or 4-D)."""
    if d == 6:
        off = 0
    elif d == 4 and getattr(task, "fixed_start", None) is not None:
        off = -2
    else:
        raise ValueError(
            "random_walk_envs needs the point-particle layout (6-D, or 4-D with fixed_start), got "
            f"d = {d}"
        )
    cw, ch, cgx, cgy = (_COLS6[k] + off for k in ("wall_x", "hole_y", "goal_x", "goal_y"))
    return cw, ch, cgx, cgy


def walk_bounds(task, env: Tensor) -> tuple[Tensor, Tensor]:
    """Lower and upper bounds ``(..., 3)`` of ``(hole_y, goal_x, goal_y)`` for environments
    ``(..., d)``: ``[1, 9]``, ``[wall_x + 1.5, 10]``, ``[0, 10]`` (the sampler's ranges)."""
    cw, _, _, _ = _walk_columns(task, env.shape[-1])
    wx = env[..., cw]  # (...)
    lo = torch.stack([torch.ones_like(wx), wx + _GOAL_MARGIN, torch.zeros_like(wx)], -1)  # (..., 3)
    hi = torch.stack(
        [torch.full_like(wx, 9.0), torch.full_like(wx, 10.0), torch.full_like(wx, 10.0)], -1
    )
    return lo, hi


def _reflect(x: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    """Fold ``x`` into ``[lo, hi]`` by reflection at the bounds (any number of times);
    a degenerate range (``hi <= lo``) gives ``lo``."""
    width = hi - lo  # (...)
    ok = width > 0
    safe = torch.where(ok, width, torch.ones_like(width))
    y = torch.remainder(x - lo, 2 * safe)  # (...) in [0, 2 width)
    y = safe - (y - safe).abs()  # (...) in [0, width]
    folded = torch.where(ok, lo + y, lo)
    return torch.where((x >= lo) & (x <= hi), x, folded)  # in range: untouched, bit for bit


# ----------------------------------------------------------------------------- random walk
def random_walk_envs(
    task,
    env0: Tensor,
    num_steps: int,
    *,
    step_std: float | Sequence[float],
    generator: torch.Generator | None = None,
) -> Tensor:
    """A bounded random walk of the hole and the goal: ``env0 (E, d) -> (E, num_steps + 1, d)``.

    ``walk[:, 0] == env0``; each step adds independent ``N(0, step_std^2)`` increments to
    ``hole_y``, ``goal_x`` and ``goal_y`` and reflects the result into ``hole_y in [1, 9]``,
    ``goal_x in [wall_x + 1.5, 10]``, ``goal_y in [0, 10]``. The start and ``wall_x`` stay fixed.

    Args:
        task: a :class:`~protorch.tasks.PointParticleTask` (6-D, or 4-D with ``fixed_start``).
        env0: ``(E, d)`` initial environments, inside the bounds above.
        num_steps: number of steps (>= 0).
        step_std: per-step std, one float for all three coordinates or three floats
            ``(hole_y, goal_x, goal_y)``; 0 gives a constant walk. Over ``n`` steps a coordinate
            moves ``step_std * sqrt(n)`` RMS (less near a bound).
        generator: CPU generator for the increments (drawn in float64 on the CPU, then moved).
    """
    env0 = check_episode_envs(task, env0)
    if isinstance(num_steps, bool) or int(num_steps) != num_steps or int(num_steps) < 0:
        raise ValueError(f"num_steps must be an int >= 0, got {num_steps!r}")
    num_steps = int(num_steps)
    scalar = isinstance(step_std, numbers.Real) and not isinstance(step_std, bool)
    stds = [step_std] * 3 if scalar else list(step_std)
    if len(stds) != 3:
        raise ValueError(
            f"step_std must be a float or 3 floats (hole_y, goal_x, goal_y), got {step_std!r}"
        )
    stds = [check_number(s, "step_std", allow_zero=True) for s in stds]
    cw, ch, cgx, cgy = _walk_columns(task, env0.shape[1])
    cols = [ch, cgx, cgy]
    lo, hi = walk_bounds(task, env0)  # (E, 3)
    x0 = env0[:, cols]  # (E, 3)
    outside = (x0 < lo - _BOUND_TOL) | (x0 > hi + _BOUND_TOL)  # (E, 3)
    if bool(outside.any()):
        e, k = (int(i) for i in outside.nonzero()[0])
        raise ValueError(
            f"env0[{e}] has {WALKED[k]} = {float(x0[e, k]):.4g} outside the walk's range "
            f"[{float(lo[e, k]):.4g}, {float(hi[e, k]):.4g}]"
        )
    n_env = env0.shape[0]
    steps = torch.randn(n_env, num_steps, 3, generator=generator, dtype=torch.float64)  # (E, S, 3)
    steps = steps * torch.tensor(stds, dtype=torch.float64)
    steps = steps.to(dtype=env0.dtype, device=env0.device)  # (E, S, 3)
    out = env0[:, None, :].repeat(1, num_steps + 1, 1)  # (E, S+1, d)
    x = x0  # (E, 3)
    # sequential: a reflected walk is not a cumulative sum (S <= a few hundred, cheap)
    walked = torch.empty(n_env, num_steps, 3, dtype=env0.dtype, device=env0.device)  # (E, S, 3)
    for s in range(num_steps):
        x = _reflect(x + steps[:, s], lo, hi)  # (E, 3)
        walked[:, s] = x
    if num_steps:
        out[:, 1:, cols] = walked
    return out
