"""The paper's own moving test of Sec. IV-B (Fig. 6), as the authors' script ``main3.py`` moves it.

In the authors' test (marcoewerton/avoid_moving_walls, ``main3.py``) the start is fixed at
``(0, 5)``; the first environment draws ``wall_x ~ U(2, 8)``, ``hole_y ~ U(1, 9)``,
``goal_x ~ U(wall_x + 1.5, 10)``, ``goal_y ~ U(0, 10)``; then, before every one of the 200
moving control steps, the wall (and with it the hole) moves by ``d_wx`` in x, the goal's x by the
same ``d_wx``, the hole by ``d_wy`` in y and the goal by ``d_gy`` in y, each step ``0.1``
(10 units/s at ``dt = 0.01``) and each reflected at its range: the wall's x in ``[2, 8]`` and
the hole's y in ``[1, 9]`` and the goal's y in ``[0, 10]`` turn back (the step is undone and
its sign flipped); the goal's x step is only undone when it would leave ``[wall_x + 1.5, 10]``
(it follows the wall, never turns on its own). After the 200 moving steps the environment
stays put for the 50 hold steps. The particle starts at rest at the start and a PD controller
(Kp 1000, Kd 30) tracks the GP mean re-inferred every step.

:func:`paper_walk` builds that sequence of environments, bit for bit the authors' arithmetic in
float64; :func:`run_paper_episodes` runs it through
:func:`protorch.control.particle.run_episodes` (``walk=``), so the tracking, the collision test
against the moving wall and the success check are those of the random-walk test. What differs
from the authors' loop: the phase of the marker is ``t / 200`` (theirs: ``t / 199``, their mean
resampled to 200 points), the integrator is semi-implicit Euler (theirs: ``x += v dt + a dt^2 / 2``)
and the marker's velocity is the analytic phase derivative (theirs: a finite difference).
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from ..checks import check_int, check_number
from .particle import EpisodeResult, run_episodes

__all__ = ["PAPER_START", "PAPER_STEP", "sample_paper_envs", "paper_walk", "run_paper_episodes"]

PAPER_START = (0.0, 5.0)  # main3.py: start_x = 0, start_y = 5
PAPER_STEP = 0.1  # main3.py: dsy, dwx, dwy, dey = 0.1 per control step
_WALL_X = (2.0, 8.0)
_HOLE_Y = (1.0, 9.0)
_GOAL_Y = (0.0, 10.0)
_GOAL_X_MAX = 10.0
_GOAL_MARGIN = 1.5


def _start(task) -> tuple[float, float]:
    fixed = getattr(task, "fixed_start", None)
    return tuple(float(v) for v in fixed) if fixed is not None else PAPER_START


def _layout(task, env: Tensor) -> Tensor:
    """``(..., d)`` environments of ``task`` -> ``(..., 4)`` ``(wall_x, hole_y,
    goal_x, goal_y)``."""
    d = int(task.env_dim)
    if env.shape[-1] != d or d not in (4, 6):
        raise ValueError(
            f"environments must be (..., {d}) for {type(task).__name__}, got shape "
            f"{tuple(env.shape)}"
        )
    return env[..., 2:6] if d == 6 else env


def _to_task(task, env4: Tensor) -> Tensor:
    """``(..., 4)`` -> the task's layout, with the fixed start in front for a 6-D task."""
    if int(task.env_dim) == 4:
        return env4
    start = env4.new_tensor(_start(task)).expand(*env4.shape[:-1], 2)  # (..., 2)
    return torch.cat([start, env4], -1)  # (..., 6)


def sample_paper_envs(
    task, n: int, generator: torch.Generator | None = None, dtype: torch.dtype = torch.float64
) -> Tensor:
    """``n`` first environments of the authors' test, ``(n, task.env_dim)``: start fixed
    (``task.fixed_start``, else ``(0, 5)``), wall, hole and goal drawn as ``main3.py`` draws
    them."""
    n = check_int(n, "n", 0)
    u = torch.rand(n, 4, generator=generator, dtype=torch.float64)  # (n, 4)
    wx = _WALL_X[0] + u[:, 0] * (_WALL_X[1] - _WALL_X[0])
    wy = _HOLE_Y[0] + u[:, 1] * (_HOLE_Y[1] - _HOLE_Y[0])
    gx = u[:, 2] * (_GOAL_X_MAX - (wx + _GOAL_MARGIN)) + wx + _GOAL_MARGIN
    gy = u[:, 3] * (_GOAL_Y[1] - _GOAL_Y[0])
    return _to_task(task, torch.stack([wx, wy, gx, gy], -1)).to(dtype)  # (n, d)


def paper_walk(
    task, env0: Tensor, num_steps: int = 200, *, step: float | Sequence[float] = PAPER_STEP
) -> Tensor:
    """The authors' moving environments: ``env0 (E, d) -> (E, num_steps + 1, d)``.

    ``walk[:, t]`` is the environment the authors' step ``t`` sees, i.e. ``env0`` changed
    ``min(t + 1, num_steps)`` times (their loop changes the environment before it is first used,
    and not after the last moving step). ``step``: the initial ``(d_wx, d_wy, d_gy)`` (one float
    for all three; main3.py: 0.1, all positive at the start). Computed in float64.
    """
    num_steps = check_int(num_steps, "num_steps", 1)
    steps = [step] * 3 if isinstance(step, (int, float)) else list(step)
    if len(steps) != 3:
        raise ValueError(f"step must be a float or 3 floats (d_wx, d_wy, d_gy), got {step!r}")
    steps = [check_number(s, "step", allow_zero=True) for s in steps]
    e4 = _layout(task, torch.as_tensor(env0)).to(torch.float64)  # (E, 4)
    if e4.ndim != 2:
        raise ValueError(f"env0 must be (E, {task.env_dim}), got shape {tuple(e4.shape)}")
    wx, wy, gx, gy = e4.unbind(-1)  # (E,) each
    dwx, dwy, dgy = (torch.full_like(wx, s) for s in steps)
    out = []
    for _ in range(num_steps):  # main3.py change_env, vectorised over the episodes
        wx = wx + dwx
        gx = gx + dwx
        gx = torch.where((gx < wx + _GOAL_MARGIN) | (gx > _GOAL_X_MAX), gx - dwx, gx)
        bad = (wx < _WALL_X[0]) | (wx > _WALL_X[1])
        wx, dwx = torch.where(bad, wx - dwx, wx), torch.where(bad, -dwx, dwx)
        wy = wy + dwy
        bad = (wy < _HOLE_Y[0]) | (wy > _HOLE_Y[1])
        wy, dwy = torch.where(bad, wy - dwy, wy), torch.where(bad, -dwy, dwy)
        gy = gy + dgy
        bad = (gy < _GOAL_Y[0]) | (gy > _GOAL_Y[1])
        gy, dgy = torch.where(bad, gy - dgy, gy), torch.where(bad, -dgy, dgy)
        out.append(torch.stack([wx, wy, gx, gy], -1))  # (E, 4)
    walk4 = torch.stack(out + [out[-1]], 1)  # (E, num_steps + 1, 4)
    return _to_task(task, walk4).to(
        torch.as_tensor(env0).dtype if torch.as_tensor(env0).is_floating_point() else torch.float64
    )


def run_paper_episodes(
    model,
    task,
    env0: Tensor,
    *,
    duration: float = 2.0,
    dt: float = 0.01,
    step: float | Sequence[float] = PAPER_STEP,
    **kwargs,
) -> EpisodeResult:
    """The authors' moving test from the first environments ``env0 (E, d)``
    (:func:`sample_paper_envs`): :func:`paper_walk` over ``duration / dt`` moving steps, then
    :func:`~protorch.control.particle.run_episodes` (``hold``, ``kp``, ``kd``, ``goal_tol``,
    ``start``, ``record`` pass through; the particle starts at rest at the fixed start)."""
    duration, dt = check_number(duration, "duration"), check_number(dt, "dt")
    if "walk" in kwargs or "step_std" in kwargs:
        raise ValueError(
            "run_paper_episodes builds the authors' walk itself: no walk= or step_std="
        )
    moving = (
        int(-(-duration // dt))
        if abs(duration / dt - round(duration / dt)) > 1e-9
        else int(round(duration / dt))
    )
    walk = paper_walk(task, env0, moving, step=step)
    return run_episodes(model, task, walk=walk, duration=duration, dt=dt, **kwargs)
