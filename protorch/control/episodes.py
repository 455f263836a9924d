"""The episode runner shared by the online tests: a system tracks the environment map's mean at
the current phase while its environment changes.

Per control step ``t = 0..T`` (``T = M + H``: ``M = ceil(duration / dt)`` moving steps, then
``H = round(hold / dt)`` steps of hold) :func:`track` asks the system for the mean weights it
tracks now (:meth:`TrackedSystem.answer`: the system updates its environment, re-infers the map
and records what it needs), evaluates that mean at the current phase ``z = min(t dt / duration, 1)``
only (the "marker" ``m`` and its velocity ``m' = d tau / dz / duration``; ``0`` during the hold),
asks the system for its acceleration towards the marker (:meth:`TrackedSystem.acceleration`) and
integrates with the semi-implicit (symplectic) Euler step

    ``v_{t+1} = v_t + a_t dt``,   ``x_{t+1} = x_t + v_{t+1} dt``.

The answer of the last instant ``T`` is recorded, not applied.

Stability of that integrator (checked before any work, :func:`check_pd_stable`,
:func:`check_velocity_loop_stable`):

* PD on a mass, ``a = (kp (m - x) + kd (m' - v)) / mass`` (the point particle). With
  ``e = x - m`` at a resting marker, one step maps ``(e, v)`` by
  ``[[1 - k h^2, h (1 - c h)], [-k h, 1 - c h]]`` with ``k = kp / mass``, ``c = kd / mass``,
  ``h = dt``: determinant ``1 - c h``, trace ``2 - c h - k h^2``. Both eigenvalues lie inside
  the unit circle (Jury) iff ``|1 - c h| < 1`` and ``|trace| < 1 + det``, i.e. iff
  ``kp dt^2 / mass + 2 kd dt / mass < 4`` (which implies ``c h < 2``). The authors' gains
  ``kp = 1000, kd = 30, mass = 1, dt = 0.01`` give 0.7.
* A commanded velocity ``v_cmd = m' + kp (m - q)`` reached in one step (the arm, when neither
  the velocity nor the acceleration limit binds: ``v_{t+1} = v_cmd``): ``e_{t+1} = (1 - kp dt)
  e_t``,
  stable iff ``kp dt < 2``.

An episode has at most :data:`MAX_STEPS` control steps (``10^6``: the runner keeps every instant
of every episode, ``E (T + 1) (2 D + N)`` floats).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor

from ..checks import check_number, check_tensor

__all__ = [
    "MAX_STEPS",
    "Timing",
    "TrackedSystem",
    "Tracked",
    "basis_derivative_at",
    "check_episode_envs",
    "check_timing",
    "check_pd_stable",
    "check_velocity_loop_stable",
    "episode_walk",
    "hold_last",
    "promp_state_at",
    "track",
]

MAX_STEPS = 1_000_000  # control steps per episode (moving + hold)


# ----------------------------------------------------------------------------- ProMP at one phase
def basis_derivative_at(promp, phase: Tensor | float) -> Tensor:
    """``d Phi / dz`` of a :class:`~protorch.primitives.promp.ProMP`'s normalised Gaussian basis at
    phases
    ``(P,)``: ``(P, K)``, ``promp.basis_at(phase, order=1)[:, 1]``
    (:func:`~protorch.primitives.promp.gaussian_basis` has the formula)."""
    return promp.basis_at(phase, order=1)[:, 1]  # (P, K)


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


# ----------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Timing:
    """The time grid of an episode: ``moving`` steps with ``z < 1``, then ``held`` steps at ``z =
    1``."""

    dt: float
    duration: float
    moving: int  # M
    held: int  # H

    @property
    def total(self) -> int:
        """``T = M + H`` control steps (``T + 1`` instants)."""
        return self.moving + self.held

    @property
    def hold(self) -> float:
        """Seconds of hold actually simulated, ``H dt``."""
        return self.held * self.dt

    def phase(self, t: int) -> float:
        """``z = min(t dt / duration, 1)`` at instant ``t``."""
        return min(t * self.dt / self.duration, 1.0)


def check_timing(dt, duration, hold) -> Timing:
    """Validate ``dt, duration > 0``, ``hold >= 0``, ``dt <= duration`` and at most
    :data:`MAX_STEPS` control steps per episode; return the episode's :class:`Timing`."""
    dt = check_number(dt, "dt")
    duration = check_number(duration, "duration")
    hold = check_number(hold, "hold", allow_zero=True)
    if dt > duration:
        raise ValueError(f"dt ({dt}) must not exceed duration ({duration})")
    moving, held = int(math.ceil(duration / dt - 1e-9)), int(round(hold / dt))
    if moving + held > MAX_STEPS:
        raise ValueError(
            f"duration + hold = {duration + hold:g} s at dt = {dt:g} s is {moving + held} control "
            "steps per episode, "
            f"over the limit of {MAX_STEPS}: use dt >= {(duration + hold) / MAX_STEPS:.3g}"
        )
    return Timing(dt=dt, duration=duration, moving=moving, held=held)


def check_pd_stable(kp: float, kd: float, mass: float, dt: float) -> None:
    """Refuse PD gains the semi-implicit Euler step cannot integrate:
    stable iff ``kp dt^2 / mass + 2 kd dt / mass < 4`` (module docstring)."""
    s = (kp * dt * dt + 2.0 * kd * dt) / mass
    if not s < 4.0:
        raise ValueError(
            f"dt = {dt:g} with kp = {kp:g}, kd = {kd:g}, mass = {mass:g} is unstable: the "
            "semi-implicit Euler "
            f"PD step needs kp dt^2 / mass + 2 kd dt / mass < 4, got {s:.4g}; use a smaller dt or "
            "smaller gains"
        )


def check_velocity_loop_stable(kp: float, dt: float) -> None:
    """Refuse a position gain the one-step velocity command cannot integrate: stable iff
    ``kp dt < 2`` (module docstring)."""
    if not kp * dt < 2.0:
        raise ValueError(
            f"dt = {dt:g} with kp = {kp:g} is unstable: the commanded joint velocity kp (m - q) "
            "reached in one step "
            f"needs kp dt < 2, got {kp * dt:.4g}; use a smaller dt or a smaller kp"
        )


def check_episode_envs(task, env0, name: str = "env0") -> Tensor:
    """``env0 (E, task.env_dim)``, finite, ``E >= 1``, as a floating tensor (float64 if it was
    not)."""
    env0 = check_tensor(env0, name, ndim=2)
    if not env0.is_floating_point():
        env0 = env0.to(torch.float64)
    d = int(task.env_dim)
    if env0.shape[1] != d:
        raise ValueError(
            f"{name} must be (E, {d}) for {type(task).__name__} (env_dim {d}), got shape "
            f"{tuple(env0.shape)}"
        )
    if env0.shape[0] < 1:
        raise ValueError(f"{name} holds no environment: shape {tuple(env0.shape)}")
    return env0


def episode_walk(
    env0: Tensor | None, walk: Tensor | None, timing: Timing, env_dim: int
) -> Tensor | None:
    """Exactly one of ``env0 (E, d)`` and ``walk (E, M + 1, d)``; returns ``walk`` checked (finite,
    3-D, ``M + 1`` instants, ``E >= 1``), or ``None`` when ``env0`` is given (checked by the
    caller)."""
    if walk is None:
        if env0 is None:
            raise ValueError(f"give env0 (E, {env_dim}), the initial environments, or walk")
        return None
    if env0 is not None:
        raise ValueError("give env0 or walk, not both")
    walk = check_tensor(walk, "walk", ndim=3)
    if walk.shape[1] != timing.moving + 1 or walk.shape[0] < 1:
        raise ValueError(
            f"walk must be (E, {timing.moving + 1}, {env_dim}) for duration {timing.duration} and "
            f"dt {timing.dt} "
            f"({timing.moving} moving steps, E >= 1), got shape {tuple(walk.shape)}"
        )
    return walk


def hold_last(walk: Tensor, held: int) -> Tensor:
    """``walk (E, M + 1, d)`` with its last environment repeated for the hold: ``(E, M + 1 + H,
    d)``."""
    return torch.cat([walk, walk[:, -1:].expand(-1, held, -1)], 1)


# ----------------------------------------------------------------------------- the time loop
class TrackedSystem(Protocol):
    """What :func:`track` needs of a system (the particle, the arm)."""

    def answer(self, t: int, z: float, x: Tensor, v: Tensor | None = None) -> Tensor:
        """The mean weights ``(E, N)`` to track at instant ``t`` (phase ``z``), the state being
        ``x, v (E, D)``: update the environment, query the map, record."""

    def acceleration(self, x: Tensor, v: Tensor, m: Tensor, m_vel: Tensor) -> Tensor:
        """``(E, D)`` acceleration at state ``x, v`` towards the marker ``m`` moving
        at ``m_vel``."""


@dataclass
class Tracked:
    """Positions and velocities of ``E`` episodes and, with ``record``, what was tracked."""

    positions: Tensor  # (E, T+1, D)
    velocities: Tensor  # (E, T+1, D)
    markers: Tensor | None  # (E, T+1, D)
    weights: Tensor | None  # (E, T+1, N)


def track(
    system: TrackedSystem,
    promp,
    timing: Timing,
    num_episodes: int,
    start: Tensor | None,
    *,
    record: bool = True,
    markers: bool = True,
) -> Tracked:
    """Run the time loop (module docstring) for ``num_episodes`` episodes starting at rest at
    ``start (E, D)`` (or ``(D,)``), or at the first marker when ``start`` is ``None``.
    Simulates in the ProMP's dtype and device."""
    ref = promp.basis
    kw = dict(dtype=ref.dtype, device=ref.device)
    n, total, d = num_episodes, timing.total, promp.num_dof
    pos = torch.empty(n, total + 1, d, **kw)  # (E, T+1, D)
    vel = torch.zeros_like(pos)  # (E, T+1, D)
    mk = torch.empty(n, total + 1, d, **kw) if record and markers else None  # (E, T+1, D)
    wt = torch.empty(n, total + 1, promp.num_weights, **kw) if record else None  # (E, T+1, N)
    if start is not None:
        pos[:, 0] = start
    dt = timing.dt
    with torch.no_grad():
        for t in range(total + 1):
            z = timing.phase(t)
            mu = system.answer(t, z, pos[:, t], vel[:, t])  # (E, N)
            m, dm_dz = promp_state_at(promp, mu, z)  # (E, D), (E, D)
            m_vel = dm_dz / timing.duration if t < timing.moving else torch.zeros_like(m)  # (E, D)
            if wt is not None:
                wt[:, t] = mu
            if mk is not None:
                mk[:, t] = m
            if t == 0 and start is None:
                pos[:, 0] = m
            if t == total:
                break
            x, v = pos[:, t], vel[:, t]  # (E, D)
            vel[:, t + 1] = v + system.acceleration(x, v, m, m_vel) * dt
            pos[:, t + 1] = x + vel[:, t + 1] * dt
    return Tracked(positions=pos, velocities=vel, markers=mk, weights=wt)
