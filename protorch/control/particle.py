"""The online test of the paper's Fig. 6: a point particle passes a hole that moves while it moves.

During an episode the hole centre and the goal follow a bounded random walk
(:func:`random_walk_envs`). At every control step the environment map is queried once for all
``E`` episodes at their current environments, the ProMP mean of each answer is evaluated at the
*current phase* only, and a PD controller drives the particle towards that point (the "marker";
the paper: "a PD controller tracks a marker moving along the mean"). :func:`run_episodes`
simulates a batch of episodes in torch and reports which succeed: the path never enters the wall
and ends within ``goal_tol`` (0.2) of the final goal.

Choices (measured with ``Kp = 1000, Kd = 30, dt = 0.01``, the authors' gains and step):

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
  have a minimum-jerk speed profile, so a path of ~12 units over 2 s peaks at ~11 units/s.
  Measured on the means a map fitted to 30 x 3 synthetic demonstrations predicts for 100 random
  static environments (particle started on the marker): tracking error median 0.010, max 0.062
  (1 s: 0.039 / 0.13; 3 s: 0.004 / 0.041); after the hold the particle is within 1e-5 of the
  mean's end (without it, 0.008). Tracking the per-environment demonstration means gives the same
  success as the means themselves (29 of 30). During the hold the map is still queried
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
:func:`random_walk_envs` is specific to the point-particle environment layout.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import torch
from torch import Tensor

from ..checks import check_number, check_tensor

__all__ = [
    "EpisodeResult",
    "random_walk_envs",
    "run_episodes",
    "promp_state_at",
    "basis_derivative_at",
    "walk_bounds",
    "WALKED",
]

# point-particle environment layout (6-D): start_x, start_y, wall_x, hole_y, goal_x, goal_y
WALKED = ("hole_y", "goal_x", "goal_y")  # the coordinates the random walk moves
_COLS6 = {"start_x": 0, "start_y": 1, "wall_x": 2, "hole_y": 3, "goal_x": 4, "goal_y": 5}
_GOAL_MARGIN = 1.5  # the sampler's goal_x >= wall_x + 1.5
_BOUND_TOL = 1e-9


# ----------------------------------------------------------------------------- validation
def _check_env0(task, env0, name: str = "env0") -> Tensor:
    env0 = check_tensor(env0, name, ndim=2)
    if not env0.is_floating_point():
        env0 = env0.to(torch.float64)
    d = int(task.env_dim)
    if env0.shape[1] != d:
        raise ValueError(
            f"{name} must be (E, {d}) for {type(task).__name__} (env_dim {d}), got shape {tuple(env0.shape)}"
        )
    if env0.shape[0] < 1:
        raise ValueError(f"{name} holds no environment: shape {tuple(env0.shape)}")
    return env0


def _walk_columns(task, d: int) -> tuple[int, int, int, int]:
    """Columns of ``wall_x, hole_y, goal_x, goal_y`` in a ``d``-D environment (6-D or 4-D)."""
    if d == 6:
        off = 0
    elif d == 4 and getattr(task, "fixed_start", None) is not None:
        off = -2
    else:
        raise ValueError(
            f"random_walk_envs needs the point-particle layout (6-D, or 4-D with fixed_start), got d = {d}"
        )
    cw, ch, cgx, cgy = (_COLS6[k] + off for k in ("wall_x", "hole_y", "goal_x", "goal_y"))
    return cw, ch, cgx, cgy


def walk_bounds(task, env: Tensor) -> tuple[Tensor, Tensor]:
    """Lower and upper bounds ``(..., 3)`` of ``(hole_y, goal_x, goal_y)`` for environments
    ``(..., d)``: ``[1, 9]``, ``[wall_x + 1.5, 10]``, ``[0, 10]`` (the sampler's ranges)."""
    cw, _, _, _ = _walk_columns(task, env.shape[-1])
    wx = env[..., cw]  # (...)
    lo = torch.stack([torch.ones_like(wx), wx + _GOAL_MARGIN, torch.zeros_like(wx)], -1)  # (..., 3)
    hi = torch.stack([torch.full_like(wx, 9.0), torch.full_like(wx, 10.0), torch.full_like(wx, 10.0)], -1)
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
    env0 = _check_env0(task, env0)
    if isinstance(num_steps, bool) or int(num_steps) != num_steps or int(num_steps) < 0:
        raise ValueError(f"num_steps must be an int >= 0, got {num_steps!r}")
    num_steps = int(num_steps)
    scalar = isinstance(step_std, numbers.Real) and not isinstance(step_std, bool)
    stds = [step_std] * 3 if scalar else list(step_std)
    if len(stds) != 3:
        raise ValueError(f"step_std must be a float or 3 floats (hole_y, goal_x, goal_y), got {step_std!r}")
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


# ----------------------------------------------------------------------------- ProMP at one phase
def basis_derivative_at(promp, phase: Tensor | float) -> Tensor:
    """``d Phi / dz`` of a :class:`~protorch.primitives.promp.ProMP`'s normalised Gaussian basis at phases
    ``(P,)``: ``(P, K)``. With ``b_k = exp(-(z - c_k)^2 / (2 w^2))``, ``g_k = b_k / sum_j b_j``
    and ``a_k = -(z - c_k) / w^2``: ``g_k' = g_k (a_k - sum_j g_j a_j)``."""
    g = promp.basis_at(phase)  # (P, K)
    z = torch.as_tensor(phase, dtype=g.dtype, device=g.device).reshape(-1, 1)  # (P, 1)
    a = -(z - promp.centers) / promp.width**2  # (P, K)
    return g * (a - (g * a).sum(-1, keepdim=True))  # (P, K)


def promp_state_at(promp, w: Tensor, phase: float) -> tuple[Tensor, Tensor]:
    """Mean position and its phase derivative at one phase: ``w (..., N) -> (..., D), (..., D)``.

    ``pos == promp.trajectory(w, phase=[z])[..., 0, :]``; ``dpos_dz`` is exact (analytic
    derivative of the basis). Costs ``O(N)`` per weight vector: only ``z`` is evaluated.
    """
    if w.shape[-1] != promp.num_weights:
        raise ValueError(f"w must end in {promp.num_weights} weights, got shape {tuple(w.shape)}")
    phi = promp.basis_at(phase)[0]  # (K,)
    dphi = basis_derivative_at(promp, phase)[0]  # (K,)
    wk = w.to(phi.dtype).unflatten(-1, (promp.num_dof, promp.num_basis))  # (..., D, K)
    return wk @ phi, wk @ dphi  # (..., D), (..., D)


# ----------------------------------------------------------------------------- episodes
@dataclass
class EpisodeResult:
    """``E`` simulated episodes of ``T`` control steps (``T + 1`` instants ``t dt``).

    Index ``t`` of every per-instant tensor is time ``t * dt``. ``markers[:, t]`` / ``weights[:, t]``
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
        """Numpy arrays of episode ``i`` for :mod:`protorch.viz.online`: ``positions (T+1, 2)``,
        ``envs (T+1, 6)`` (full 6-D), ``means (T+1, P, 2)`` (the mean trajectory predicted at each
        instant; needs ``record=True``), ``markers (T+1, 2)``, ``dt``, ``success``."""
        if not -self.num_episodes <= i < self.num_episodes:
            raise IndexError(f"episode {i} out of range for {self.num_episodes} episodes")
        if self.weights is None or self.markers is None:
            raise ValueError("this result was run with record=False: no markers or mean trajectories to plot")
        envs = self.envs[i]
        if self.task is not None and envs.shape[-1] != 6:
            envs = self.task.full_env(envs)
        means = self.promp.trajectory(self.weights[i]) if self.promp is not None else None  # (T+1, P, D)
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
            :class:`~protorch.data.checkpoint.EnvToProMP`, anything with ``.env_map.predict_mean`` or
            ``.predict_mean``, or a callable ``env (E, d) -> (mu (E, N), var)``. A bare callable
            needs ``promp=``.
        task: the task (``env_dim``, ``full_env``, ``collides``), e.g. ``PointParticleTask``.
        env0: ``(E, d)`` initial environments; the episodes' environments follow
            :func:`random_walk_envs` from them. Give ``walk`` instead to prescribe them.
        duration: seconds for the phase to go from 0 to 1 (the moving part).
        hold: seconds after that with the marker at the mean's end (``z = 1``, velocity 0) and
            the environment frozen at its last walked value.
        dt, kp, kd, mass: control step, PD gains, particle mass (``acc = PD / mass``,
            semi-implicit Euler: ``v += acc dt; x += v dt``).
        step_std: per-step std of the walk; ``None``: ``1 / sqrt(moving steps)``, i.e. each
            walked coordinate moves 1 unit RMS over the motion. 0 freezes the environment.
        walk: ``(E, M + 1, d)`` prescribed environments for the ``M = ceil(duration / dt)``
            moving steps (then frozen for the hold), instead of a random walk from ``env0``.
        start: ``"env"`` (rest at the environment's start) or ``"marker"`` (rest at the first marker).
        goal_tol: success radius around the final goal.
        generator: CPU generator of the random walk.
        promp: the ProMP, when ``model`` has no ``.promp``.
        labels: passed to ``predict_mean`` (maps with several label groups).
        record: keep the markers and predicted weights of every instant (for plots).

    The map is queried ``T + 1`` times, once per instant ``t = 0..T`` (``T = M + hold / dt``)
    with the ``E`` current environments in one batch; the answer at ``t < T`` sets the marker of
    control step ``t``, the last one is only recorded.
    """
    # ---------------------------------------------------------------- validation
    promp = promp if promp is not None else getattr(model, "promp", None)
    if promp is None or not hasattr(promp, "basis_at") or not hasattr(promp, "num_weights"):
        raise ValueError("model must have a .promp (a protorch ProMP), or pass promp=")
    predict = _predictor(model, labels)
    dt = check_number(dt, "dt")
    duration = check_number(duration, "duration")
    hold = check_number(hold, "hold", allow_zero=True)
    kp = check_number(kp, "kp")
    kd = check_number(kd, "kd")
    mass = check_number(mass, "mass")
    goal_tol = check_number(goal_tol, "goal_tol", allow_zero=True)
    if start not in ("env", "marker"):
        raise ValueError(f"start must be 'env' or 'marker', got {start!r}")
    if dt > duration:
        raise ValueError(f"dt ({dt}) must not exceed duration ({duration})")
    if promp.num_dof != 2:
        raise ValueError(f"the particle is 2-D: the ProMP must have 2 DoF, got {promp.num_dof}")
    moving = int(math.ceil(duration / dt - 1e-9))  # M: steps with z < 1
    held = int(round(hold / dt))
    if walk is not None:
        if env0 is not None:
            raise ValueError("give env0 or walk, not both")
        if step_std is not None:
            raise ValueError(
                "step_std applies to the random walk from env0; walk prescribes the environments"
            )
        walk = check_tensor(walk, "walk", ndim=3)
        if not walk.is_floating_point():
            walk = walk.to(torch.float64)
        _check_env0(task, walk[:, 0], "walk[:, 0]")
        if walk.shape[1] != moving + 1:
            raise ValueError(
                f"walk must be (E, {moving + 1}, {task.env_dim}) for duration {duration} and dt {dt} "
                f"({moving} moving steps), got shape {tuple(walk.shape)}"
            )
    else:
        if env0 is None:
            raise ValueError("give env0 (E, d), the initial environments, or walk")
        env0 = _check_env0(task, env0)
        if step_std is None:
            step_std = 1.0 / math.sqrt(moving)
        walk = random_walk_envs(task, env0, moving, step_std=step_std, generator=generator)
    ref = promp.basis  # dtype / device of the simulation
    kw = dict(dtype=ref.dtype, device=ref.device)
    walk = walk.to(**kw)
    envs = torch.cat([walk, walk[:, -1:].expand(-1, held, -1)], 1)  # (E, T+1, d)
    n_env, total = envs.shape[0], moving + held  # E, T

    # ---------------------------------------------------------------- simulation
    pos = torch.empty(n_env, total + 1, 2, **kw)  # (E, T+1, 2)
    vel = torch.zeros(n_env, total + 1, 2, **kw)  # (E, T+1, 2)
    markers = torch.empty(n_env, total + 1, 2, **kw) if record else None  # (E, T+1, 2)
    weights = torch.empty(n_env, total + 1, promp.num_weights, **kw) if record else None  # (E, T+1, N)
    with torch.no_grad():
        for t in range(total + 1):
            mu = predict(envs[:, t])  # (E, N)
            if tuple(mu.shape) != (n_env, promp.num_weights):
                raise ValueError(
                    f"the model returned mean weights of shape {tuple(mu.shape)}, "
                    f"expected ({n_env}, {promp.num_weights})"
                )
            mu = mu.to(**kw)
            z = min(t * dt / duration, 1.0)
            m, dm_dz = promp_state_at(promp, mu, z)  # (E, 2), (E, 2)
            m_vel = dm_dz / duration if t < moving else torch.zeros_like(m)  # (E, 2)
            if record:
                markers[:, t], weights[:, t] = m, mu
            if t == 0:
                pos[:, 0] = _start_of(task, envs[:, 0]) if start == "env" else m
            if t == total:
                break
            x, v = pos[:, t], vel[:, t]  # (E, 2)
            acc = (kp * (m - x) + kd * (m_vel - v)) / mass  # (E, 2)
            vel[:, t + 1] = v + acc * dt
            pos[:, t + 1] = x + vel[:, t + 1] * dt

        # ------------------------------------------------------------ outcome
        seg = torch.stack([pos[:, :-1], pos[:, 1:]], -2)  # (E, T, 2, 2) segment t: x_t -> x_{t+1}
        hit = task.collides(seg, envs[:, :-1]) | task.collides(seg, envs[:, 1:])  # (E, T)
        collided = hit.any(-1)  # (E,)
        dist = (pos[:, -1] - _goal_of(task, envs[:, -1])).norm(dim=-1)  # (E,)
    return EpisodeResult(
        positions=pos, velocities=vel, envs=envs, markers=markers, weights=weights,
        success=~collided & (dist <= goal_tol), collided=collided, final_goal_distance=dist,
        dt=dt, duration=duration, hold=held * dt, num_moving_steps=moving, goal_tol=goal_tol,
        promp=promp, task=task,
    )
