"""A task that lives outside protorch: a 2-D point reaches a goal around a disc obstacle.

    python -m protorch experiment=self_improve
    task._target_=examples.reach_around_a_disc.ReachAroundADisc

Environment ``(cx, cy, gx, gy)``: the disc's centre and the goal; the start is the origin. The
demonstrations pass above the disc with a hand-picked, noisy clearance, so some of them clip it:
the self-improvement loop has something to improve.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class ReachAroundADisc:
    radius: float = 0.15  # the disc's radius
    tol: float = 0.05  # start / goal error that counts as reached
    clearance_std: float = 0.06  # spread of the demonstrations' clearance above the disc
    name: str = "reach_around_a_disc"
    num_dof: int = 2  # D: a point in the plane
    env_dim: int = 4  # E: (cx, cy, gx, gy)

    def sample_envs(
        self, n: int, generator: torch.Generator, dtype: torch.dtype = torch.float64
    ) -> Tensor:
        u = torch.rand(n, 4, generator=generator, dtype=torch.float64)
        lo = torch.tensor([0.4, -0.1, 0.9, -0.2], dtype=torch.float64)
        hi = torch.tensor([0.6, 0.1, 1.1, 0.2], dtype=torch.float64)
        return (lo + u * (hi - lo)).to(dtype)  # (n, 4)

    def _parts(self, traj: Tensor, env: Tensor):
        env = env.to(traj)
        centre, goal = env[..., None, :2], env[..., 2:]  # (..., 1, 2), (..., 2)
        start_err = traj[..., 0, :].norm(dim=-1)  # (...)
        goal_err = (traj[..., -1, :] - goal).norm(dim=-1)  # (...)
        gap = (traj - centre).norm(dim=-1).min(
            -1
        ).values - self.radius  # (...) closest approach to the disc
        return start_err, gap, goal_err

    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """``(..., T, 2)``, ``(..., 4)`` -> ``(..., 3)``: start error, penetration (0.05 m margin),
        goal error."""
        start_err, gap, goal_err = self._parts(traj, env)
        return torch.stack([start_err, (0.05 - gap).clamp_min(0.0), goal_err], -1)

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        start_err, gap, goal_err = self._parts(traj, env)
        return (start_err < self.tol) & (goal_err < self.tol) & (gap > 0)

    def demonstrations(
        self, num_envs: int, per_env: int, generator: torch.Generator
    ) -> tuple[list[Tensor], Tensor]:
        """Quadratic Bezier curves from the origin over the disc to the goal, ``T = 100``."""
        envs = self.sample_envs(num_envs, generator).repeat_interleave(per_env, 0)  # (n, 4)
        s = torch.linspace(0, 1, 100, dtype=torch.float64)[:, None]  # (T, 1)
        demos = []
        for env in envs:
            clear = (
                self.radius
                + 0.02
                + self.clearance_std * torch.randn((), generator=generator, dtype=torch.float64)
            )
            mid = (
                env[:2] + torch.tensor([0.0, 1.0], dtype=torch.float64) * clear
            )  # where the curve crosses the disc
            start, goal = torch.zeros(2, dtype=torch.float64), env[2:]
            ctrl = 2 * mid - 0.5 * (start + goal)  # the curve passes `mid` at s = 0.5
            noise = 0.01 * torch.randn(2, generator=generator, dtype=torch.float64)
            demos.append(
                (1 - s) ** 2 * start + 2 * s * (1 - s) * (ctrl + noise) + s**2 * goal
            )  # (T, 2)
        return demos, envs
