"""The moving test's episodes driven by a :class:`~protorch.policy.policy.Policy`: the class
choice and the mean the arm tracks come from the policy's planner, inline, a fixed number of
control steps behind (deterministic), or from the real planner thread while the episode's clock
advances in real time.

The episodes are the moving test's own: its environments at every instant (``envs (E, T+1, 4)``,
e.g. those of a run's kinematic moving test, replayed as the physics test replays them), its
control step ``dt``, its velocity command following the tracked mean's marker
(:func:`~protorch.control.episodes.track`, kinematics) or its MuJoCo plant and computed-torque
controller (:func:`~protorch.control.physics.run_physics_episodes`). Only the system that names the
mean to track every control step changes: :class:`PolicyMeans`, one episode at a time.

* ``mode="inline"``: every control step the policy's planner step (the class choice of
  :meth:`~protorch.policy.policy.Policy.reference`, from the environment and the measured joints of
  that instant) and its plan tracked at once: the moving test's choice.
* ``mode="lagged"``: the same plans, each tracked ``lag`` control steps after the instant whose
  inputs it was made from (the motion's first plan, made at ``t = 0`` as
  :meth:`~protorch.policy.policy.Policy.reset` makes it, until then): the planner a step behind,
  deterministically.
* ``mode="thread"``: a policy with ``planner="thread"``; every control step waits for its instant
  of the wall clock, hands the inputs to :meth:`~protorch.policy.policy.Policy.reference` and
  tracks the newest plan the planner thread published (whatever its age: not deterministic).
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import Tensor

from ..policy.limits import make_limiter, robot_limits
from ..policy.policy import Policy
from ..policy.two_rate import Tracker
from .arm import arm_outcome, count_switches
from .arm_choice import velocity_command_acceleration
from .episodes import Timing, track
from .physics import run_physics_episodes

__all__ = ["MODES", "PolicyMeans", "policy_copy", "run_policy_episodes"]

MODES = ("inline", "lagged", "thread")


def policy_copy(policy, **options):
    """A new :class:`~protorch.policy.policy.Policy` on ``policy``'s map, task and settings
    (``options`` override them: ``planner``, ``limits``, ...), without warm-up."""
    follow = policy.follow
    kw = dict(
        task=policy.task,
        duration=policy.duration,
        switch_margin=policy.switch_margin,
        decision_dt=policy.decision_dt,
        blend=policy.blend,
        experiment=policy.experiment,
        check=policy.check,
        switch_clearance=policy.switch_clearance,
        warm_up=False,
    )
    if follow is not None:
        kw.update(kp=follow.kp, max_acceleration=follow.amax.tolist())
    kw.update(options)
    return Policy(policy._P, policy.env_map, policy.task_name, **kw)


class PolicyMeans:
    """The system of :func:`~protorch.control.episodes.track` and
    :func:`~protorch.control.physics.run_physics_episodes` (module docstring): ``answer(t, z, q (E,
    J), qd (E, J)) -> (E, N)`` the mean weights of the plan each episode tracks at instant ``t``.
    ``policies``: one per episode (each keeps its motion's state; ``mode="thread"``: one episode);
    ``envs (E, T+1, 4)``; :attr:`labels` ``(E, T+1)`` the tracked class, :attr:`age` ``(E, T+1)``
    the seconds between the instant and the inputs of its plan. ``follow="reference"``: the
    policy's reference (``mode="thread"``: :meth:`~protorch.policy.policy.Policy.reference`; else
    the tracker it runs, :class:`~protorch.policy.two_rate.Tracker`, with ``limits`` the
    policy's ``limits`` for ``planner="thread"``, :func:`~protorch.policy.limits.make_limiter`)
    kept in :attr:`ref` ``(E, 2, D)`` for the arm and in :attr:`states` ``(E, T+1, 3, D)``; in
    MuJoCo (:meth:`reference_markers`) also at every physics step. :attr:`peaks` ``(E, 5)``: over
    every tick at which the reference was computed, the largest ``|qd| / max_velocity``, ``|qdd|
    / max_acceleration``, ``|qdd - qdd_last| / (tick max_jerk)``, ``|q - q_last| / (tick
    max_velocity)`` and ``|qd - qd_last| / (tick max_acceleration)`` (the robot's limits,
    :func:`~protorch.policy.limits.robot_limits`; the last three: finite differences at the
    tick)."""

    def __init__(
        self,
        policies,
        envs: Tensor,
        timing: Timing,
        mode: str,
        lag: int = 1,
        *,
        follow: str = "mean",
        limits: bool | str = "auto",
    ) -> None:
        if follow not in ("mean", "reference"):
            raise ValueError(f"follow must be 'mean' or 'reference', got {follow!r}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        policies = list(policies)
        want = "thread" if mode == "thread" else "inline"
        if any(p.planner != want for p in policies):
            raise ValueError(f"mode={mode!r} needs policies with planner={want!r}")
        if mode == "thread" and len(policies) != 1:
            raise ValueError("mode='thread' runs one episode at a time (its clock is the wall's)")
        if envs.dim() != 3 or envs.shape[0] != len(policies):
            raise ValueError(
                f"envs must be (E, T+1, env_dim) with E = {len(policies)} policies, got "
                f"{tuple(envs.shape)}"
            )
        if not (isinstance(lag, int) and lag >= 0):
            raise ValueError(f"lag must be an int >= 0 (control steps), got {lag!r}")
        self.policies, self.mode, self.timing = policies, mode, timing
        self.lag = lag if mode == "lagged" else 0
        self.envs = envs.detach().to(torch.float64).cpu().numpy()  # (E, T+1, 4)
        e, n = self.envs.shape[:2]
        self.labels = torch.zeros(e, n, dtype=torch.long)  # (E, T+1) as ArmClassChoice's
        self.age = np.zeros((e, n))  # (E, T+1)
        self._plans: list[list] = [[] for _ in policies]  # each episode's plans, one per instant
        self._start = 0.0  # the wall clock at t = 0 (thread)
        self.follow = follow
        self.ref = torch.zeros(e, 2, policies[0]._d, dtype=torch.float64)  # (E, 2, D) q_r, qd_r
        self.states = np.zeros((e, n, 3, policies[0]._d))  # (E, T+1, 3, D) the references
        self._trackers = (
            [_tracker(p, limits) for p in policies]
            if follow == "reference" and mode != "thread"
            else None
        )
        self._current: list = [None] * e  # the plan each episode tracks now
        self.peaks = np.zeros((e, 5))  # (E, 5) the reference's largest ratios to the limits
        self._last: list = [None] * e  # (3, D) each episode's last reference and its time
        self._lim = (
            robot_limits(policies[0].task.robot, policies[0]._d) if follow == "reference" else None
        )

    def answer(self, t: int, z: float, q: Tensor, qd: Tensor | None = None) -> Tensor:
        s = t * self.timing.dt
        q_np = q.detach().to(torch.float64).cpu().numpy()  # (E, J)
        qd_np = None if qd is None else qd.detach().to(torch.float64).cpu().numpy()  # (E, J)
        out = []
        for e, pol in enumerate(self.policies):
            env, qe = self.envs[e, t], q_np[e]
            qde = None if qd_np is None else qd_np[e]
            if self.mode == "thread":
                if t == 0:
                    pol.reset(env, qe, qde)  # the motion's first plan, before its first tick
                    self._last[e] = None
                    self._start = time.perf_counter()
                wait = self._start + s - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                r = pol.reference(env, s, qe, qde)
                plan = pol._tracker.plan
                self.states[e, t] = torch.stack([r.q, r.qd, r.qdd]).numpy()
                self.ref[e] = torch.from_numpy(self.states[e, t, :2])
                self._peak(e, s, self.states[e, t])
            else:
                if t == 0:
                    pol.reset()
                    self._last[e] = None
                    if self._trackers is not None:
                        self._trackers[e].reset()
                self._plans[e].append(pol._plan(0, env, s, qe, qde))
                plan = self._plans[e][max(t - self.lag, 0)]
                if self._trackers is not None:  # the tracker's reference, at the control step
                    self.states[e, t] = self._trackers[e].step(s, plan, qe, qde)
                    self.ref[e] = torch.from_numpy(self.states[e, t, :2])
                    self._peak(e, s, self.states[e, t])
            self._current[e] = plan
            self.labels[e, t], self.age[e, t] = plan.label, s - plan.t
            out.append(plan.W.T.reshape(-1))  # (N,) = (D Kb), the weights' layout
        return torch.from_numpy(np.stack(out)).to(q.dtype)  # (E, N)

    def reference_markers(
        self, t: int, times: Tensor, m: Tensor, m_vel: Tensor
    ) -> tuple[Tensor, Tensor]:
        """The markers the MuJoCo reference follows at the physics steps ``times (n,)`` of control
        step ``t`` (:func:`~protorch.control.physics.run_physics_episodes`): the plan's mean's,
        ``m, m_vel (E, n, D)``, as they are (``follow="mean"``), or the policy's reference at each
        physics step (``follow="reference"``: the tracker stepped at every physics step on the
        plan of control step ``t``, its limiter too)."""
        if self.follow != "reference":
            return m, m_vel
        if self._trackers is None:
            raise ValueError("follow='reference' in MuJoCo runs modes 'inline' and 'lagged'")
        out = np.empty((len(self.policies), len(times), 2, m.shape[-1]))  # (E, n, 2, D)
        for e, tracker in enumerate(self._trackers):
            for i, s in enumerate(times.tolist()):
                if i == 0:  # control step t itself: computed by answer()
                    out[e, i] = self.states[e, t, :2]
                    continue
                k = round(s * 1000.0)  # a whole millisecond: the tracker's basis table
                s = k * 1e-3 if abs(k * 1e-3 - s) < 1e-9 else s
                state = tracker.step(s, self._current[e], None, None)  # (3, D)
                self._peak(e, s, state)
                out[e, i] = state[:2]
        ref = torch.from_numpy(out).to(m)
        return ref[:, :, 0], ref[:, :, 1]

    def _peak(self, e: int, s: float, state: np.ndarray) -> None:
        """Keep episode ``e``'s largest ratios to the limits (:attr:`peaks`) with the reference
        ``state (3, D)`` at time ``s``."""
        if self._lim is None:
            return
        vmax, amax, jmax = self._lim
        last = self._last[e]
        row = [np.abs(state[1] / vmax).max(), np.abs(state[2] / amax).max(), 0.0, 0.0, 0.0]
        if last is not None and s > last[0]:
            tick = s - last[0]
            row[2] = np.abs((state[2] - last[1][2]) / (tick * jmax)).max()
            row[3] = np.abs((state[0] - last[1][0]) / (tick * vmax)).max()
            row[4] = np.abs((state[1] - last[1][1]) / (tick * amax)).max()
        self._last[e] = (s, state.copy())
        np.maximum(self.peaks[e], row, out=self.peaks[e])


def run_policy_episodes(
    policy,
    envs: Tensor,
    timing: Timing,
    mode: str,
    *,
    lag: int = 1,
    kp: float = 10.0,
    max_acceleration=None,
    physics: dict | None = None,
    follow: str = "mean",
    limits: bool | str = "auto",
) -> dict:
    """The moving test's episodes in ``envs (E, T+1, 4)`` with :class:`PolicyMeans` naming the
    means (module docstring): all at once with a copy of ``policy`` per episode
    (:func:`policy_copy`, ``planner="inline"``), or, ``mode="thread"``, one at a time with a copy
    with ``planner="thread"`` (its thread stopped after the episode). ``kp``,
    ``max_acceleration`` (``None``: the robot's): the velocity command (the run's
    ``settings.dynamic``). ``physics``: ``None`` for the kinematic test, else the keyword
    arguments of :func:`~protorch.control.physics.run_physics_episodes` (``scene``, ``ctrl_model``,
    ``kp``, ``kd``, ``ref_kp``, ``max_acceleration``, ``feasible``).

    Returns ``success (E,)`` bool, ``labels (E, T+1)``, ``age (E, T+1)`` (seconds), ``switches
    (E,)``, ``q (E, T+1, J)``, ``states (E, T+1, 3, J)`` (the reference at the control steps,
    ``follow="reference"``; zeros otherwise), ``peaks (E, 5)`` (:attr:`PolicyMeans.peaks`) as
    NumPy arrays, and ``failures`` (physics: per failure ``(E,)``).

    ``follow="reference"``: the arm's velocity command follows the policy's reference
    (:meth:`~protorch.policy.policy.Policy.reference`'s tracker: the plan's mean plus the
    continuity offset; ``limits``: the policy's ``limits`` for ``planner="thread"``, by default
    held to the robot's velocity, acceleration and jerk limits, ``False`` not) instead of the
    tracked plan's mean: in kinematics evaluated at the control step, in MuJoCo at every physics
    step (modes ``inline`` and ``lagged``)."""
    if follow == "reference" and physics is not None and mode == "thread":
        raise ValueError("follow='reference' in MuJoCo runs modes 'inline' and 'lagged'")
    task, promp = policy.task, policy._P
    if envs.dim() != 3 or envs.shape[1] != timing.total + 1:
        raise ValueError(
            f"envs must be (E, {timing.total + 1}, env_dim) for this timing, got "
            f"{tuple(envs.shape)}"
        )
    amax = task.robot.max_acceleration if max_acceleration is None else max_acceleration
    kw = {"dtype": promp.basis.dtype, "device": promp.basis.device}
    if mode == "thread":
        groups = [[e] for e in range(envs.shape[0])]
    else:
        groups = [list(range(envs.shape[0]))]
    parts = []
    for idx in groups:
        opts = {"planner": "thread", "limits": limits} if mode == "thread" else {}
        pols = [policy_copy(policy, **opts) for _ in idx]
        try:
            parts.append(
                _run(pols, envs[idx], timing, mode, lag, kp, amax, physics, kw, follow, limits)
            )
        finally:
            for p in pols:
                p.close()
    lab = np.concatenate([p["labels"] for p in parts])  # (E, T+1)
    fails = [p["failures"] for p in parts]
    return {
        "success": np.concatenate([p["success"] for p in parts]),
        "labels": lab,
        "age": np.concatenate([p["age"] for p in parts]),
        "switches": count_switches(torch.from_numpy(lab)).numpy(),
        "q": np.concatenate([p["q"] for p in parts]),
        "states": np.concatenate([p["states"] for p in parts]),
        "peaks": np.concatenate([p["peaks"] for p in parts]),
        "failures": {k: np.concatenate([f[k] for f in fails]) for k in fails[0]},
    }


def _run(pols, envs: Tensor, timing: Timing, mode, lag, kp, amax, physics, kw, follow, limits):
    """One batch of episodes (:func:`run_policy_episodes`)."""
    task, promp = pols[0].task, pols[0]._P
    system = PolicyMeans(pols, envs, timing, mode, lag, follow=follow, limits=limits)
    if physics is None:
        arm = _Arm(system, task, timing, kp, amax, kw)
        run = track(arm, promp, timing, len(pols), task.start_config(**kw), record=False)
        out = arm_outcome(task, run.positions, envs.to(**kw))
        success, q, failures = out["success"].cpu().numpy(), run.positions.cpu().numpy(), {}
    else:
        res = run_physics_episodes(
            system=system, promp=promp, timing=timing, envs=envs.cpu(), **physics
        )
        success, q, failures = res.success, res.q, dict(res.failures)
    return {
        "success": np.asarray(success, dtype=bool),
        "labels": system.labels.numpy(),
        "age": system.age,
        "states": system.states,
        "peaks": system.peaks,
        "q": q,
        "failures": failures,
    }


def _tracker(policy, limits):
    """The tracker ``planner="thread"`` with ``limits`` gives ``policy``
    (:class:`~protorch.policy.two_rate.Tracker` with the limiter of
    :func:`~protorch.policy.limits.make_limiter`: ``"auto"``, ``True``, ``"joint"``
    :class:`~protorch.policy.limits.JointwiseLimiter`, ``"together"``
    :class:`~protorch.policy.limits.JerkLimiter`, ``False`` none), without its thread."""
    lim = make_limiter(limits, "thread", policy.task.robot, policy._d)
    P = policy._P
    return Tracker(
        policy._phi_ms.cpu().numpy(),
        P.centers.to(torch.float64).cpu().numpy(),
        float(P.width),
        policy.duration,
        policy.blend,
        lim,
    )


class _Arm:
    """The kinematic arm of :func:`~protorch.control.arm.run_arm_episodes` around a system."""

    def __init__(self, system: PolicyMeans, task, timing: Timing, kp: float, amax, kw) -> None:
        self.system, self.dt, self.kp = system, timing.dt, float(kp)
        self.vmax = task.kinematics.max_velocity.to(**kw)  # (J,)
        self.amax = torch.as_tensor(amax, **kw).expand(task.num_dof)  # (J,)
        self._command = velocity_command_acceleration

    def answer(self, t: int, z: float, q: Tensor, qd: Tensor | None = None) -> Tensor:
        return self.system.answer(t, z, q, qd)

    def acceleration(self, q: Tensor, qd: Tensor, m: Tensor, m_vel: Tensor) -> Tensor:
        if self.system.follow == "reference":  # the policy's reference, not the plan's mean
            m, m_vel = self.system.ref[:, 0].to(q), self.system.ref[:, 1].to(q)  # (E, D)
        return self._command(
            q, qd, m, m_vel, kp=self.kp, vmax=self.vmax, amax=self.amax, dt=self.dt
        )
