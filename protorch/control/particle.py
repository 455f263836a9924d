"""The online test of the paper's Fig. 6: a point particle passes a hole that moves while it moves.

During an episode the hole centre and the goal follow a bounded random walk
(:func:`random_walk_envs`). At every control step the environment map is queried once for all
``E`` episodes at their current environments, the ProMP mean of each answer is evaluated at the
*current phase* only, and a PD controller drives the particle towards that point (the "marker";
the paper: "a PD controller tracks a marker moving along the mean"). :func:`run_episodes`
simulates a batch of episodes in torch and reports which succeed: the path never enters the wall
and ends within ``goal_tol`` (0.2) of the final goal.

Choices (for ``Kp = 1000, Kd = 30, dt = 0.01``, the authors' gains and step):

* **Re-timing.** The phase runs at a fixed rate, ``z(t) = min(t dt / duration, 1)``. When the
  environment changes, the marker jumps to the new mean trajectory *at the current phase*; it
  does not restart the new trajectory from its beginning. Its velocity, used by the D term, is the
  time derivative along the phase, ``d tau / dz / duration`` (exact derivative of the normalised
  Gaussian basis); the change of the trajectory with the environment is not differentiated.
  Both cost ``O(N)`` per episode and step: the basis is evaluated at ``z`` alone.
* **Velocity feed-forward, hence no lag.** With the marker's velocity inside the D term,
  ``acc = Kp (m - x) + Kd (m' - v)``, the tracking error obeys ``e'' + Kd e' + Kp e = m''``: a
  marker moving at constant velocity is tracked with zero steady error (without the feed-forward
  the lag would be ``Kd / Kp |v| = 0.03 |v|``, 0.3 at 10 units/s). What remains is about
  ``|m''| / Kp``; the closed loop has ``omega = 31.6 rad/s``, damping ratio 0.47.
* **Duration 2 s + 0.5 s hold** (defaults), as in the authors' script (200 moving steps, then 50
  steps at the end of the mean while the environment stays put). The synthetic demonstrations
  have a minimum-jerk speed profile, so a path of ~12 units over 2 s peaks at ~11 units/s; the
  hold lets the particle settle on the mean's end. During the hold the map is still queried
  every step (on the frozen final environment) and the marker sits at ``z = 1``, velocity 0.
* **Start.** The particle starts at rest at the environment's start (``start="env"``, the
  authors' choice: the particle is where it is; a mean that starts off the start costs a short
  transient). ``start="marker"`` starts it at the first marker instead.
* **Random walk.** Independent Gaussian steps on ``hole_y``, ``goal_x``, ``goal_y``, reflected
  into the sampler's ranges (``hole_y in [1, 9]``, ``goal_x in [wall_x + 1.5, 10]``,
  ``goal_y in [0, 10]``); start and ``wall_x`` stay fixed. Default per-step std
  ``1 / sqrt(moving steps)`` (0.0707 at 200 steps): each coordinate moves 1 unit RMS over the
  motion. (The authors' script instead bounces every coordinate, the wall included, at a
  constant 0.1 per step; pass such a sequence as ``walk``.)
* **Success.** Every segment ``x_t -> x_{t+1}`` of the simulated path is checked with the task's
  exact segment test against the wall at both instants ``t`` and ``t + 1`` (the hole moves), and
  ``||x_T - goal_T|| <= goal_tol``. The start is not checked (the particle starts there).

Task-agnostic parts: :func:`run_episodes` uses only ``task.env_dim``, ``task.full_env`` (start
``[..., 0:2]`` and goal ``[..., 4:6]`` of the 6-D environment, or ``task.start(env)`` /
``task.goal(env)`` when the task defines them) and ``task.collides(traj, env)``;
:func:`random_walk_envs` (:mod:`protorch.control.walk`) is specific to the point-particle
environment layout. The time loop (query, marker, PD step, record) is
:func:`protorch.control.episodes.track`, shared with the arm (:mod:`protorch.control.arm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import torch
from torch import Tensor

from ..checks import check_number
from .episodes import (
    Timing,
    basis_derivative_at,
    check_episode_envs,
    check_pd_stable,
    check_timing,
    episode_walk,
    hold_last,
    promp_state_at,
    track,
)
from .walk import WALKED, random_walk_envs, walk_bounds

__all__ = [
    "EpisodeResult",
    "random_walk_envs",
    "run_episodes",
    "promp_state_at",
    "basis_derivative_at",
    "walk_bounds",
    "WALKED",
]


# ----------------------------------------------------------------------------- episodes
@dataclass
class EpisodeResult:
    """``E`` simulated episodes of ``T`` control steps (``T + 1`` instants ``t dt``).

    Index ``t`` of every per-instant tensor is time ``t * dt``. ``markers[:, t]`` / ``weights[:,
    t]``
    are what the map answered for ``envs[:, t]`` (the last instant's answer is recorded, not
    applied). ``markers`` and ``weights`` are ``None`` with ``record=False``.
    """

    positions: Tensor  # (E, T+1, 2)
    velocities: Tensor  # (E, T+1, 2)
    envs: Tensor  # (E, T+1, d)
    markers: Tensor | None  # (E, T+1, 2)
    weights: Tensor | None  # (E, T+1, N) predicted mean weights
    success: Tensor  # (E,) bool
    collided: Tensor  # (E,) bool
    final_goal_distance: Tensor  # (E,)
    dt: float
    duration: float
    hold: float
    num_moving_steps: int  # steps with z < 1; the rest is the hold
    goal_tol: float
    promp: Any = field(default=None, repr=False)
    task: Any = field(default=None, repr=False)

    @property
    def success_rate(self) -> float:
        return float(self.success.to(torch.float64).mean())

    @property
    def num_episodes(self) -> int:
        return self.positions.shape[0]

    @property
    def num_steps(self) -> int:
        """``T``, control steps (moving + hold)."""
        return self.positions.shape[1] - 1

    @property
    def times(self) -> Tensor:
        """``(T + 1,)`` seconds."""
        return torch.arange(self.num_steps + 1, dtype=torch.float64) * self.dt

    @property
    def phases(self) -> Tensor:
        """``(T + 1,)`` phase of each instant, ``min(t dt / duration, 1)``."""
        return (self.times / self.duration).clamp(max=1.0)

    def summary(self) -> dict:
        """JSON-able numbers: success rate, collision rate, final goal distances."""
        d = self.final_goal_distance
        return {
            "episodes": self.num_episodes,
            "success_rate": self.success_rate,
            "collision_rate": float(self.collided.to(torch.float64).mean()),
            "final_goal_distance_mean": float(d.mean()),
            "final_goal_distance_median": float(d.median()),
            "goal_reached_rate": float((d <= self.goal_tol).to(torch.float64).mean()),
        }

    def episode(self, i: int) -> dict:
        """Numpy arrays of episode ``i`` for :mod:`protorch.figures.online`: ``positions (T+1, 2)``,
        ``envs (T+1, 6)`` (full 6-D), ``means (T+1, P, 2)`` (the mean trajectory predicted at each
        instant; needs ``record=True``), ``markers (T+1, 2)``, ``dt``, ``success``."""
        if not -self.num_episodes <= i < self.num_episodes:
            raise IndexError(f"episode {i} out of range for {self.num_episodes} episodes")
        if self.weights is None or self.markers is None:
            raise ValueError(
                "this result was run with record=False: no markers or mean trajectories to plot"
            )
        envs = self.envs[i]
        if self.task is not None and envs.shape[-1] != 6:
            envs = self.task.full_env(envs)
        means = (
            self.promp.trajectory(self.weights[i]) if self.promp is not None else None
        )  # (T+1, P, D)
        np_ = lambda x: None if x is None else x.detach().cpu().numpy()  # noqa: E731
        return {
            "positions": np_(self.positions[i]),
            "envs": np_(envs),
            "means": np_(means),
            "markers": np_(self.markers[i]),
            "dt": self.dt,
            "success": bool(self.success[i]),
        }


def _predictor(model, labels) -> Callable[[Tensor], Tensor]:
    """``env (E, d) -> mu (E, N)``: ``model.env_map.predict_mean`` (or ``model.predict_mean``)
    when there is one, else ``model(env)[0]``."""
    kw = {} if labels is None else {"labels": labels}
    env_map = getattr(model, "env_map", None)
    if env_map is not None and callable(getattr(env_map, "predict_mean", None)):
        return lambda e: env_map.predict_mean(e, **kw)
    if callable(getattr(model, "predict_mean", None)):
        return lambda e: model.predict_mean(e, **kw)
    if callable(model):
        return lambda e: model(e, **kw)[0]
    raise ValueError(
        f"model must have .env_map.predict_mean, .predict_mean, or be callable env -> (mu, var); "
        f"got {type(model).__name__}"
    )


def _start_of(task, env: Tensor) -> Tensor:
    if callable(getattr(task, "start", None)):
        return task.start(env)
    return task.full_env(env)[..., 0:2]


def _goal_of(task, env: Tensor) -> Tensor:
    if callable(getattr(task, "goal", None)):
        return task.goal(env)
    return task.full_env(env)[..., 4:6]


def run_episodes(
    model,
    task,
    env0: Tensor | None = None,
    *,
    duration: float = 2.0,
    hold: float = 0.5,
    dt: float = 0.01,
    kp: float = 1000.0,
    kd: float = 30.0,
    mass: float = 1.0,
    step_std: float | Sequence[float] | None = None,
    walk: Tensor | None = None,
    start: str = "env",
    goal_tol: float = 0.2,
    generator: torch.Generator | None = None,
    promp=None,
    labels=None,
    record: bool = True,
) -> EpisodeResult:
    """Simulate ``E`` online episodes at once (float64, on the ProMP's device).

    Args:
        model: ``model.promp`` (a :class:`~protorch.primitives.promp.ProMP`) and a prediction: an
            :class:`~protorch.data.checkpoint.EnvToProMP`, anything with ``.env_map.predict_mean``
            or
            ``.predict_mean``, or a callable ``env (E, d) -> (mu (E, N), var)``. A bare callable
            needs ``promp=``.
        task: the task (``env_dim``, ``full_env``, ``collides``), e.g. ``PointParticleTask``.
        env0: ``(E, d)`` initial environments; the episodes' environments follow
            :func:`random_walk_envs` from them. Give ``walk`` instead to prescribe them.
        duration: seconds for the phase to go from 0 to 1 (the moving part).
        hold: seconds after that with the marker at the mean's end (``z = 1``, velocity 0) and
            the environment frozen at its last walked value.
        dt, kp, kd, mass: control step, PD gains, particle mass (``acc = PD / mass``,
            semi-implicit Euler: ``v += acc dt; x += v dt``). Refused unless the step is stable,
            ``kp dt^2 / mass + 2 kd dt / mass < 4`` (derived in :mod:`protorch.control.episodes`;
            the defaults give 0.7), and unless an episode has at most
            :data:`~protorch.control.episodes.MAX_STEPS` (``10^6``) control steps.
        step_std: per-step std of the walk; ``None``: ``1 / sqrt(moving steps)``, i.e. each
            walked coordinate moves 1 unit RMS over the motion. 0 freezes the environment.
        walk: ``(E, M + 1, d)`` prescribed environments for the ``M = ceil(duration / dt)``
            moving steps (then frozen for the hold), instead of a random walk from ``env0``.
        start: ``"env"`` (rest at the environment's start) or ``"marker"`` (rest at the first
        marker).
        goal_tol: success radius around the final goal.
        generator: CPU generator of the random walk.
        promp: the ProMP, when ``model`` has no ``.promp``.
        labels: passed to ``predict_mean`` (maps with several label groups).
        record: keep the markers and predicted weights of every instant (for plots).

    The map is queried ``T + 1`` times, once per instant ``t = 0..T`` (``T = M + hold / dt``)
    with the ``E`` current environments in one batch; the answer at ``t < T`` sets the marker of
    control step ``t``, the last one is only recorded.
    """
    promp = promp if promp is not None else getattr(model, "promp", None)
    if promp is None or not hasattr(promp, "basis_at") or not hasattr(promp, "num_weights"):
        raise ValueError("model must have a .promp (a protorch ProMP), or pass promp=")
    predict = _predictor(model, labels)
    timing = check_timing(dt, duration, hold)
    kp, kd, mass = check_number(kp, "kp"), check_number(kd, "kd"), check_number(mass, "mass")
    check_pd_stable(kp, kd, mass, timing.dt)
    goal_tol = check_number(goal_tol, "goal_tol", allow_zero=True)
    if start not in ("env", "marker"):
        raise ValueError(f"start must be 'env' or 'marker', got {start!r}")
    if promp.num_dof != 2:
        raise ValueError(f"the particle is 2-D: the ProMP must have 2 DoF, got {promp.num_dof}")
    envs = _episode_envs(task, env0, walk, step_std, timing, generator).to(
        promp.basis
    )  # (E, T+1, d)
    pd = _ParticlePD(predict, envs, promp.num_weights, kp, kd, mass)
    first = (
        _start_of(task, envs[:, 0]) if start == "env" else None
    )  # (E, 2), None: the first marker
    run = track(pd, promp, timing, envs.shape[0], first, record=record)
    pos = run.positions  # (E, T+1, 2)
    with torch.no_grad():
        seg = torch.stack([pos[:, :-1], pos[:, 1:]], -2)  # (E, T, 2, 2) segment t: x_t -> x_{t+1}
        hit = task.collides(seg, envs[:, :-1]) | task.collides(seg, envs[:, 1:])  # (E, T)
        collided = hit.any(-1)  # (E,)
        dist = (pos[:, -1] - _goal_of(task, envs[:, -1])).norm(dim=-1)  # (E,)
    return EpisodeResult(
        positions=pos,
        velocities=run.velocities,
        envs=envs,
        markers=run.markers,
        weights=run.weights,
        success=~collided & (dist <= goal_tol),
        collided=collided,
        final_goal_distance=dist,
        dt=timing.dt,
        duration=timing.duration,
        hold=timing.hold,
        num_moving_steps=timing.moving,
        goal_tol=goal_tol,
        promp=promp,
        task=task,
    )


def _episode_envs(task, env0, walk, step_std, timing: Timing, generator) -> Tensor:
    """The environments of every instant ``(E, T+1, d)``: the prescribed ``walk`` or a random walk
    from ``env0``, then frozen for the hold."""
    walk = episode_walk(env0, walk, timing, task.env_dim)
    if walk is not None:
        if step_std is not None:
            raise ValueError(
                "step_std applies to the random walk from env0; walk prescribes the environments"
            )
        if not walk.is_floating_point():
            walk = walk.to(torch.float64)
        check_episode_envs(task, walk[:, 0], "walk[:, 0]")
    else:
        env0 = check_episode_envs(task, env0)
        if step_std is None:
            step_std = 1.0 / math.sqrt(timing.moving)
        walk = random_walk_envs(task, env0, timing.moving, step_std=step_std, generator=generator)
    return hold_last(walk, timing.held)


class _ParticlePD:
    """The point particle for :func:`~protorch.control.episodes.track`: the map's answer for the
    environments of each instant, PD acceleration ``(kp (m - x) + kd (m' - v)) / mass``."""

    def __init__(
        self, predict, envs: Tensor, num_weights: int, kp: float, kd: float, mass: float
    ) -> None:
        self.predict, self.envs, self.num_weights = predict, envs, num_weights  # envs (E, T+1, d)
        self.kp, self.kd, self.mass = kp, kd, mass

    def answer(self, t: int, z: float, x: Tensor, v: Tensor | None = None) -> Tensor:
        mu = self.predict(self.envs[:, t])  # (E, N)
        n_env = self.envs.shape[0]
        if tuple(mu.shape) != (n_env, self.num_weights):
            raise ValueError(
                f"the model returned mean weights of shape {tuple(mu.shape)}, expected ({n_env}, "
                f"{self.num_weights})"
            )
        return mu.to(self.envs)

    def acceleration(self, x: Tensor, v: Tensor, m: Tensor, m_vel: Tensor) -> Tensor:
        return (self.kp * (m - x) + self.kd * (m_vel - v)) / self.mass  # (E, 2)
