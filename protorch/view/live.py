"""The moving-environment controllers, one control step at a time, for the viewer's play button.

The batch simulators (:func:`protorch.control.particle.run_episodes`,
:func:`protorch.control.arm.run_arm_episodes`) take the whole environment sequence up front; here
the environment is whatever the person has dragged it to when the step runs. The control laws are
theirs: the particle's PD (``Kp 1000, Kd 30, dt 0.01``) tracks the marker, the mean of the map's
answer at the current phase, with its phase velocity as feed-forward; the arm tracks the chosen
class's mean joint trajectory (``v_cmd = m' + kp (m - q)`` clamped to the joint velocity limits,
reached within the acceleration limits), the class chosen as the moving test and a trained run's
policy choose it (:meth:`protorch.control.policy.Policy.choose`: the objectives of the rest of the
motion from where the arm is, the switch margin, the plan check with its own hysteresis).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..control.arm import run_arm_episodes
from ..control.arm_choice import velocity_command_acceleration
from ..control.particle import promp_state_at
from ..control.policy import Policy
from ..control.policy_settings import policy_settings
from ..tasks.arm.collision import above_table
from ..tasks.arm.reach import SIDES

__all__ = ["ArmPlayer", "ParticlePlayer", "make_player"]


class _Player:
    """Shared clock: ``duration`` seconds of motion (phase 0 -> 1), then ``hold`` at the end."""

    def __init__(self, run, *, duration: float, hold: float, dt: float) -> None:
        if not (dt > 0 and duration >= dt and hold >= 0):
            raise ValueError(
                f"need 0 < dt <= duration and hold >= 0, got dt={dt}, duration={duration}, hold="
                f"{hold}"
            )
        self.run, self.dt, self.duration = run, float(dt), float(duration)
        self.moving = int(math.ceil(duration / dt - 1e-9))
        self.total = self.moving + int(round(hold / dt))
        ref = run.model.promp.basis
        self.kw = dict(dtype=ref.dtype, device=ref.device)
        self.t = 0
        self.done = False
        self.success: bool | None = None
        self.started = False  # reset() was called

    def _env(self, env) -> Tensor:
        return self.run.clamp(env).to(**self.kw)  # (E,)

    @property
    def phase(self) -> float:
        return min(self.t * self.dt / self.duration, 1.0)


class ParticlePlayer(_Player):
    """The PD particle of :mod:`protorch.control.particle`, stepped against a live environment."""

    def __init__(
        self,
        run,
        *,
        duration: float = 2.0,
        hold: float = 0.5,
        dt: float = 0.01,
        kp: float = 1000.0,
        kd: float = 30.0,
        goal_tol: float = 0.2,
    ) -> None:
        super().__init__(run, duration=duration, hold=hold, dt=dt)
        self.kp, self.kd, self.goal_tol = float(kp), float(kd), float(goal_tol)
        self.pos = self.vel = None

    def reset(self, env) -> None:
        """At rest at the environment's start, phase 0."""
        e = self.run.task.full_env(self._env(env))  # (6,)
        self.pos, self.vel = e[0:2].clone(), torch.zeros(2, **self.kw)  # (2,), (2,)
        self.path = [self.pos.clone()]
        self.t, self.done, self.success, self.collided = 0, False, None, False
        self.started = True

    def step(self, env) -> Tensor:
        """One control step in ``env (E,)``; returns the new position ``(2,)``."""
        if self.pos is None:
            self.reset(env)
        if self.done:
            return self.pos
        e = self._env(env)  # (E,)
        promp = self.run.model.promp
        with torch.no_grad():
            mu = self.run.model.env_map.predict_mean(e[None])  # (1, N)
            m, dm_dz = promp_state_at(promp, mu[0], self.phase)  # (2,), (2,)
            m_vel = dm_dz / self.duration if self.t < self.moving else torch.zeros_like(m)
            acc = self.kp * (m - self.pos) + self.kd * (m_vel - self.vel)  # (2,)
            self.vel = self.vel + acc * self.dt
            new = self.pos + self.vel * self.dt  # (2,)
            seg = torch.stack([self.pos, new])[None]  # (1, 2, 2)
            self.collided |= bool(self.run.task.collides(seg, e[None])[0])
        self.pos = new
        self.path.append(new.clone())
        self.t += 1
        if self.t >= self.total:
            goal = self.run.task.full_env(e)[4:6]
            self.done = True
            self.success = (not self.collided) and float((new - goal).norm()) <= self.goal_tol
        return self.pos

    def trace(self):
        """The particle's path so far, ``(t + 1, 3)`` numpy (``z = 0``)."""
        p = torch.stack(self.path)  # (t+1, 2)
        return torch.cat([p, torch.zeros_like(p[:, :1])], -1).cpu().numpy()


class ArmPlayer(_Player):
    """The tracking arm of :mod:`protorch.control.arm`, stepped against a live environment: the
    class chosen at every step by the run's policy (:meth:`protorch.control.policy.Policy.choose`:
    the moving test's choice, its plan check and both hysteresis, one implementation), tracked by
    the moving test's velocity command; the gap to the can and the table under the task's
    collision model. The settings are the run's moving test's (``settings.dynamic`` of its
    ``config.yaml``, the test's defaults for a run without one); ``options`` override them
    (:func:`~protorch.control.policy_settings.policy_settings`)."""

    def __init__(self, run, **options) -> None:
        dyn = dict((run.config.get("settings") or {}).get("dynamic") or {})
        hold = float(options.pop("hold", dyn.get("hold", 1.0)))
        settings = policy_settings(
            dyn, moving_test=run_arm_episodes, velocity_command=True, **options
        )
        super().__init__(run, duration=settings["duration"], hold=hold, dt=settings["decision_dt"])
        model, task = run.model, run.task
        self.policy = Policy(
            model.promp, model.env_map, model.task_name, task=task, warm_up=False, **settings
        )
        follow = (
            self.policy.follow
        )  # the moving test's velocity command (max_acceleration None: the robot's)
        self.kp, self.vmax, self.amax = (
            follow.kp,
            follow.vmax.to(**self.kw),
            follow.amax.to(**self.kw),
        )  # (J,) each
        self.cand = self.policy.labels  # (K,)
        self.q = None

    def reset(self, env=None) -> None:
        """At rest at the task's start configuration, phase 0, no class chosen yet."""
        self.q = self.run.task.start_config(**self.kw)  # (J,)
        self.qd = torch.zeros_like(self.q)
        self.current, self.switches, self.min_distance = None, 0, float("inf")
        self.t, self.done, self.success, self.collided, self.valid = 0, False, None, False, True
        self.started = True
        self.policy.reset()
        self.ee = [self.run.task.kinematics.ee_position(self.q)]

    @property
    def label(self) -> str | None:
        return (
            None
            if self.current is None
            else SIDES.get(int(self.cand[self.current]), str(self.current))
        )

    def _clearance(self, e: Tensor) -> tuple[float, bool]:
        """The arm's gap to the can of ``e (4,)`` and whether it is above the table, now (from the
        chain's frames, as the moving test checks them, under the task's collision model)."""
        task = self.run.task
        frames = task.kinematics.frames(self.q[None, None])  # (1, 1, F, 4, 4)
        return float(task.frames_gap(frames, e[None])[0]), bool(above_table(task, frames)[0])

    def step(self, env) -> Tensor:
        """One control step in ``env (4,)``; returns the joint angles ``(J,)``."""
        if self.q is None:
            self.reset()
        if self.done:
            return self.q
        e, task = self._env(env), self.run.task
        with torch.no_grad():
            best, w = self.policy.choose(
                e, self.t * self.dt, self.q, qd=self.qd
            )  # (1, N) the class's mean
            self.switches += int(self.current is not None and best != self.current)
            self.current = best
            m, dm_dz = promp_state_at(
                self.run.model.promp, w[0].to(**self.kw), self.phase
            )  # (J,), (J,)
            m_vel = dm_dz / self.duration if self.t < self.moving else torch.zeros_like(m)
            acc = velocity_command_acceleration(
                self.q[None],
                self.qd[None],
                m[None],
                m_vel[None],
                kp=self.kp,
                vmax=self.vmax,
                amax=self.amax,
                dt=self.dt,
            )[0]  # (J,)
            self.qd = self.qd + acc * self.dt
            self.q = self.q + self.qd * self.dt
            gap, table = self._clearance(e)
            ee = task.kinematics.ee_position(self.q)  # (3,)
        self.min_distance = min(self.min_distance, gap)
        self.collided |= gap <= task.margin
        self.valid &= bool(task.kinematics.within_limits(self.q)) and table
        self.ee.append(ee)
        self.t += 1
        if self.t >= self.total:
            goal = float((ee - task.goal_point(e)).norm())
            self.done = True
            self.success = (not self.collided) and self.valid and goal <= task.goal_tol
        return self.q

    def trace(self):
        """The end effector's path so far, ``(t + 1, 3)`` numpy."""
        return torch.stack(self.ee).cpu().numpy()


def make_player(run):
    """The run's controller: :class:`ParticlePlayer` or :class:`ArmPlayer`."""
    return ParticlePlayer(run) if run.kind == "particle" else ArmPlayer(run)
