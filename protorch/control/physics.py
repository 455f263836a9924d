"""Arm episodes executed in MuJoCo: the map's mean tracked by the inverse-dynamics controller.

Time: control steps of ``dt`` (the kinematic test's, 0.02 s) at instants ``t = 0..T``, each split
into ``n = dt / h`` physics steps of MuJoCo's timestep ``h``. At every control step the
*system* names the mean weights ``(E, N)`` to track (:meth:`TrackedSystem.answer
<protorch.control.episodes.TrackedSystem.answer>` with the measured joints): the moving test's
:class:`~protorch.control.arm_choice.ArmClassChoice` (the map queried, the class chosen with
hysteresis, exactly as in the kinematic test) or :class:`FixedMeans` (the held-out test: one mean
per environment). The can and the target (mocap bodies) are put where the environment of that
instant has them.

At every physics step a reference ``(q_r, v_r, a_r)`` follows the mean's marker at the current
phase with the kinematic test's velocity command
(:func:`~protorch.control.arm_choice.velocity_command_acceleration`: marker velocity plus ``kp``
times the error, within the joint velocity and acceleration limits; with ``feasible`` its
acceleration scaled down where the torque it needs would pass that fraction of the limits),
integrated like MuJoCo's semi-implicit Euler step; the computed-torque controller
(:mod:`protorch.sim.controller`) tracks
it, its torques clipped to the limits, and the batch of ``E`` simulations steps once.

Per episode: the measured joints and joint velocities, the torques applied, the reference, the can
and the target at every instant, MuJoCo's
arm-can and arm-table contacts at every physics step (``contact[:, t]``: any in the physics steps
ending at instant ``t``; at ``t = 0`` the initial state's), the largest ``|tau| / limit`` commanded,
the RMS of ``q_r - q`` and whether the simulation diverged (MuJoCo raised, warned, or the state
became non-finite; that simulation stops and keeps its last state). An episode succeeds when it has
none of the failures :attr:`PhysicsEpisodes.failures` names: ``can_contact``, ``table_contact``,
``limits`` (a joint outside its limits at a physics step), ``goal`` (the tool centre point farther
than ``goal_tol`` from the final target after the hold), ``saturated`` (a commanded torque beyond a
limit, as a real Panda's torque reflex would stop it) and ``diverged``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ..sim.controller import ComputedTorque
from ..sim.mj import load_mujoco
from ..threads import torch_threads
from .arm_choice import velocity_command_acceleration
from .episodes import Timing, basis_derivative_at

__all__ = ["FixedMeans", "PhysicsEpisodes", "run_physics_episodes", "substeps", "FAILURES"]

FAILURES = ("can_contact", "table_contact", "limits", "goal", "saturated", "diverged")


class FixedMeans:
    """A system that tracks one mean per episode, ``means (E, N)``, whatever happens."""

    def __init__(self, means: Tensor) -> None:
        self.means = means

    def answer(self, t: int, z: float, q: Tensor, qd: Tensor | None = None) -> Tensor:
        return self.means


def substeps(dt: float, timestep: float) -> int:
    """``dt / timestep`` when it is a whole number >= 1, else a clear error."""
    n = int(round(dt / timestep))
    if n < 1 or abs(n * timestep - dt) > 1e-9 * max(dt, 1.0):
        raise ValueError(
            f"the control step dt = {dt:g} s must be a whole multiple of the physics timestep "
            f"{timestep:g} s"
        )
    return n


@dataclass
class PhysicsEpisodes:
    """``E`` physics episodes (module docstring); arrays are numpy."""

    q: np.ndarray  # (E, T+1, J) measured joint positions at the control instants
    qd: np.ndarray  # (E, T+1, J) measured joint velocities at the same instants
    # (E, T+1, J) torques applied (clipped) in the physics step from each instant (at T: the last
    # one)
    tau: np.ndarray
    q_ref: np.ndarray  # (E, T+1, J) the reference at the same instants
    can: np.ndarray  # (E, T+1, 2)
    target: np.ndarray  # (E, T+1, 2)
    contact: np.ndarray  # (E, T+1) bool
    can_contact_steps: np.ndarray  # (E,) physics steps with an arm-can contact
    table_contact_steps: np.ndarray  # (E,)
    deepest: np.ndarray  # (E,) most negative contact distance MuJoCo reported (0: none)
    max_torque_ratio: (
        np.ndarray
    )  # (E,) largest |tau| / limit commanded, before clipping (inf: a non-finite command)
    tracking_rms: np.ndarray  # (E,) RMS over physics steps and joints of q_r - q (rad)
    within_limits: np.ndarray  # (E,) bool
    diverged: np.ndarray  # (E,) bool
    final_goal_distance: np.ndarray  # (E,)
    labels: np.ndarray | None  # (E, T+1) the tracked class, where the system chooses one
    dt: float
    timestep: float
    goal_tol: float
    seconds: float = 0.0
    task: object = field(default=None, repr=False)

    @property
    def num_episodes(self) -> int:
        return self.q.shape[0]

    @property
    def failures(self) -> dict[str, np.ndarray]:
        """Each named failure, ``(E,)`` bool (an episode may have several)."""
        return {
            "can_contact": self.can_contact_steps > 0,
            "table_contact": self.table_contact_steps > 0,
            "limits": ~self.within_limits,
            "goal": ~(self.final_goal_distance <= self.goal_tol),
            "saturated": self.max_torque_ratio > 1.0,
            "diverged": self.diverged,
        }

    @property
    def success(self) -> np.ndarray:
        """``(E,)`` bool: none of the failures."""
        return ~np.any(np.stack(list(self.failures.values())), 0)

    def summary(self, kinematic: np.ndarray | None = None) -> dict:
        """JSON-able numbers; with ``kinematic (E,)`` (the same episodes' kinematic verdicts) also
        their agreement with the physics verdicts."""
        ok = self.success
        fail = self.failures
        finite = self.max_torque_ratio[np.isfinite(self.max_torque_ratio)]
        out = {
            "episodes": self.num_episodes,
            "success_rate": float(ok.mean()),
            "contacts": int((self.can_contact_steps + self.table_contact_steps > 0).sum()),
            "can_contacts": int(fail["can_contact"].sum()),
            "table_contacts": int(fail["table_contact"].sum()),
            "contact_steps": int((self.can_contact_steps + self.table_contact_steps).sum()),
            "deepest_contact": float(self.deepest.min()) if self.num_episodes else 0.0,
            "tracking_rms": float(np.median(self.tracking_rms)),
            "tracking_rms_max": float(self.tracking_rms.max()),
            "max_torque_ratio": float(finite.max()) if finite.size else None,
            "max_torque_ratio_median": float(np.median(finite)) if finite.size else None,
            "nonfinite_torque_episodes": int((~np.isfinite(self.max_torque_ratio)).sum()),
            "final_goal_distance_median": float(np.median(self.final_goal_distance)),
            "failures": {k: int(v.sum()) for k, v in fail.items()},
            "dt": self.dt,
            "timestep": self.timestep,
            "seconds": round(self.seconds, 3),
        }
        if kinematic is not None:
            kin = np.asarray(kinematic, dtype=bool)
            out.update(
                agreement=float((kin == ok).mean()),
                kinematic_success_physics_failure=int((kin & ~ok).sum()),
                kinematic_failure_physics_success=int((~kin & ok).sum()),
            )
        return out


def _markers(promp, w: Tensor, phases: Tensor) -> tuple[Tensor, Tensor]:
    """The mean and its phase derivative at ``phases (n,)`` for weights ``w (E, N)``: ``(E, n, D)``
    twice, float64 on the CPU."""
    ref = promp.basis
    wk = w.to(ref).unflatten(-1, (promp.num_dof, promp.num_basis))  # (E, D, K)
    phases = phases.to(ref)
    phi, dphi = promp.basis_at(phases), basis_derivative_at(promp, phases)  # (n, K)
    m = torch.einsum("edk,nk->end", wk, phi)  # (E, n, D)
    dm = torch.einsum("edk,nk->end", wk, dphi)  # (E, n, D)
    return m.to(torch.float64).cpu(), dm.to(torch.float64).cpu()


class _Plant:
    """``E`` simulations of the scene in one persistent ``mujoco.batch.Batch``, stepped on
    ``threads`` threads; a simulation that fails stops and is marked diverged."""

    def __init__(self, scene, num: int, q0: np.ndarray, threads: int) -> None:
        mujoco = load_mujoco()
        self.mujoco, self.scene = mujoco, scene
        self.batch = mujoco.batch.Batch(scene.model, num, nthread=threads, persistent=True)
        self.qpos, self.qvel = self.batch.bind("qpos"), self.batch.bind("qvel")  # (E, J)
        self.ctrl, self.mocap = (
            self.batch.bind("ctrl"),
            self.batch.bind("mocap_pos"),
        )  # (E, J), (E, 2, 3)
        self.qpos[:] = q0
        self.qvel[:] = 0.0
        self.alive = np.ones(num, dtype=bool)
        self.stage = int(mujoco.mjtStage.mjSTAGE_VEL)
        self.sensors = self.batch.bind("sensordata")  # (E, S)
        self.warned = (
            self.batch.warning[..., 1].sum(-1).copy()
        )  # (E,) MuJoCo's warning counts so far

    def place(self, can: np.ndarray, target: np.ndarray, height: float, can_height: float) -> None:
        """The can and the target of every simulation at ``can, target (E, 2)``."""
        sc = self.scene
        self.mocap[:, sc.can_mocap, :2], self.mocap[:, sc.can_mocap, 2] = can, can_height / 2
        self.mocap[:, sc.target_mocap, :2], self.mocap[:, sc.target_mocap, 2] = target, height

    def step(self) -> None:
        """One physics step of every live simulation (the position and velocity stages of the new
        state computed, as the controller's next reading needs them)."""
        ids = np.flatnonzero(self.alive)
        if ids.size == 0:
            return
        try:
            self.batch.step(ids=ids, stage=self.stage)
        except self.mujoco.batch.SimulationError as exc:
            self.alive[exc.ids] = False
        warned = self.batch.warning[..., 1].sum(
            -1
        )  # (E,) a warning (e.g. bad acceleration) resets a simulation
        bad = (
            ~np.isfinite(self.qpos).all(1) | ~np.isfinite(self.qvel).all(1) | (warned > self.warned)
        )
        self.alive &= ~bad

    def forward(self) -> None:
        self.batch.forward(stage=self.stage)


class _Recorder:
    """What :func:`run_physics_episodes` keeps of every instant and every physics step."""

    def __init__(self, num: int, total: int, dof: int) -> None:
        self.q = np.zeros((num, total + 1, dof))
        self.qd = np.zeros((num, total + 1, dof))
        self.tau = np.zeros((num, total + 1, dof))
        self.q_ref = np.zeros((num, total + 1, dof))
        self.envs = np.zeros((num, total + 1, 4))
        self.contact = np.zeros((num, total + 1), dtype=bool)
        self.can_steps = np.zeros(num, dtype=np.int64)
        self.table_steps = np.zeros(num, dtype=np.int64)
        self.deepest = np.zeros(num)
        self.ratio = np.zeros(num)
        self.sq_err, self.steps = np.zeros(num), 0
        self.within = np.ones(num, dtype=bool)

    def instant(self, t: int, plant: _Plant, q_r: Tensor, env: np.ndarray) -> None:
        self.q[:, t], self.q_ref[:, t], self.envs[:, t] = plant.qpos, q_r.numpy(), env
        self.qd[:, t] = plant.qvel

    def contacts(self, plant: _Plant, scene, t: int) -> None:
        """MuJoCo's arm-can and arm-table contact counts and depths of every live simulation."""
        data, live = plant.sensors, plant.alive
        can, table = data[:, scene.can_contact] > 0, data[:, scene.table_contact] > 0  # (E,)
        can, table = can & live, table & live
        self.can_steps += can
        self.table_steps += table
        depth = np.minimum(
            np.where(can, data[:, scene.can_contact + 1], 0.0),
            np.where(table, data[:, scene.table_contact + 1], 0.0),
        )
        self.deepest = np.minimum(self.deepest, depth)
        self.contact[:, t] |= can | table

    def torque(self, tau: Tensor, limits: Tensor, live: np.ndarray) -> None:
        ratio = (tau.abs() / limits).amax(-1).numpy()  # (E,)
        self.ratio = np.where(
            live, np.maximum(self.ratio, np.nan_to_num(ratio, nan=np.inf)), self.ratio
        )

    def physics_step(
        self, t: int, plant: _Plant, scene, q_r: Tensor, lo: np.ndarray, hi: np.ndarray
    ) -> None:
        q, live = plant.qpos, plant.alive
        self.contacts(plant, scene, t)
        self.sq_err += np.where(live, np.square(q_r.numpy() - q).mean(-1), 0.0)
        self.steps += 1
        self.within &= ~live | ((q >= lo) & (q <= hi)).all(-1)

    def result(
        self, plant: _Plant, task, timing: Timing, h: float, system, seconds: float
    ) -> PhysicsEpisodes:
        kin = task.kinematics
        with torch.no_grad():
            tcp = kin.ee_position(torch.from_numpy(self.q[:, -1])).numpy()  # (E, 3)
        goal = np.linalg.norm(
            tcp - np.concatenate([self.envs[:, -1, 2:], np.full((len(tcp), 1), task.ee_height)], 1),
            axis=-1,
        )
        labels = getattr(system, "labels", None)
        return PhysicsEpisodes(
            q=self.q,
            qd=self.qd,
            tau=self.tau,
            q_ref=self.q_ref,
            can=self.envs[..., :2].copy(),
            target=self.envs[..., 2:].copy(),
            contact=self.contact,
            can_contact_steps=self.can_steps,
            table_contact_steps=self.table_steps,
            deepest=self.deepest,
            max_torque_ratio=self.ratio,
            tracking_rms=np.sqrt(self.sq_err / max(self.steps, 1)),
            within_limits=self.within,
            diverged=~plant.alive,
            final_goal_distance=goal,
            labels=None if labels is None else labels.cpu().numpy(),
            dt=timing.dt,
            timestep=h,
            goal_tol=task.goal_tol,
            seconds=seconds,
            task=task,
        )


def run_physics_episodes(
    scene,
    ctrl_model,
    system,
    promp,
    timing: Timing,
    envs: Tensor,
    *,
    kp: float,
    kd: float,
    ref_kp: float,
    max_acceleration,
    threads: int = 1,
    feasible: float | None = None,
) -> PhysicsEpisodes:
    """Run ``E`` episodes in the environments ``envs (E, T+1, 4)`` (module docstring).

    ``scene``: the plant (:func:`~protorch.sim.scene.build_scene`); ``ctrl_model``: the
    controller's model (:func:`~protorch.sim.scene.controller_model`); ``system``: what answers
    the mean weights every control step (a system with a method ``reference_markers(t, times (n,),
    m, m_vel (E, n, D)) -> (m, m_vel)`` replaces the mean's marker and its velocity at the
    physics steps of control step ``t`` with its own reference,
    :class:`~protorch.control.policy_episodes.PolicyMeans`); ``kp, kd``: the computed-torque
    gains; ``ref_kp``,
    ``max_acceleration``: the reference's velocity command (the kinematic test's ``kp`` and
    acceleration limits); ``threads``: the thread pools of the plant's and the controller's
    batches; ``feasible``: a fraction of the torque limits within which the reference's
    acceleration is scaled to keep the command
    (:meth:`~protorch.sim.controller.ComputedTorque.feasible_torques`),
    or ``None``: the reference as planned.

    ``threads`` are MuJoCo's (its batches give the same bits at any thread count); the torch
    operations of every step (the markers, the system's answers, the torques) run on one torch
    thread, because MKL's matrix products under a pinned code path (the app's ``MKL_CBWR``) give
    other last bits on two threads than on one from about 100 episodes on (the markers' ``(E D, K)
    @ (K, n)`` product), and the episodes carry such a bit into their contacts and torques."""
    t_start = time.perf_counter()
    task, e_num, total = scene.task, envs.shape[0], timing.total
    h = scene.timestep
    n_sub = substeps(timing.dt, h)
    ctrl = ComputedTorque(ctrl_model, e_num, kp=kp, kd=kd, threads=threads)
    kw: dict[str, Any] = dict(dtype=torch.float64)
    kin = task.kinematics
    vmax, lo, hi = kin.max_velocity.to(**kw).cpu(), kin.lower.cpu().numpy(), kin.upper.cpu().numpy()
    amax = torch.as_tensor(max_acceleration, **kw).expand(task.num_dof)
    q0 = task.start_config(**kw)
    plant = _Plant(scene, e_num, q0.numpy(), threads)
    envs_np = envs.detach().cpu().numpy().astype(np.float64)
    rec = _Recorder(e_num, total, task.num_dof)
    q_r, v_r = q0.expand(e_num, -1).clone(), torch.zeros(e_num, task.num_dof, **kw)
    limits = torch.from_numpy(scene.torque_limits)
    bound = None if feasible is None else float(feasible) * limits  # (J,)
    with (
        torch.no_grad(),
        torch_threads(1),
    ):  # torch's part on one thread: the same bits at any ``threads``
        for t in range(total + 1):
            plant.place(envs_np[:, t, :2], envs_np[:, t, 2:], task.ee_height, task.can_height)
            if t == 0:
                plant.forward()
                rec.contacts(plant, scene, 0)
            rec.instant(t, plant, q_r, envs_np[:, t])
            mu = (
                system.answer(
                    t,
                    timing.phase(t),
                    torch.from_numpy(plant.qpos.copy()),
                    torch.from_numpy(plant.qvel.copy()),
                )
                .to(**kw)
                .cpu()
            )  # (E, N)
            if t == total:
                break
            times = t * timing.dt + h * torch.arange(
                n_sub, **kw
            )  # (n,) the physics steps' start times
            m, dm = _markers(promp, mu, (times / timing.duration).clamp(max=1.0))  # (E, n, D)
            m_vel = (
                dm / timing.duration * (times < timing.duration - 1e-12)[None, :, None]
            )  # (E, n, D)
            follow = getattr(system, "reference_markers", None)
            if follow is not None:  # a system with its own reference to follow (policy_episodes)
                m, m_vel = follow(t, times, m, m_vel)  # (E, n, D) twice
            for s in range(n_sub):
                a_r = velocity_command_acceleration(
                    q_r, v_r, m[:, s], m_vel[:, s], kp=ref_kp, vmax=vmax, amax=amax, dt=h
                )  # (E, J)
                if bound is None:
                    tau = ctrl.torques(plant.qpos, plant.qvel, q_r, v_r, a_r)  # (E, J)
                else:
                    tau, a_r = ctrl.feasible_torques(
                        plant.qpos, plant.qvel, q_r, v_r, a_r, bound
                    )  # (E, J) twice
                rec.torque(tau, limits, plant.alive)
                plant.alive &= (
                    torch.isfinite(tau).all(-1).numpy()
                )  # a broken command: that simulation stops here
                plant.ctrl[:] = torch.nan_to_num(
                    torch.maximum(torch.minimum(tau, limits), -limits)
                ).numpy()
                if s == 0:
                    rec.tau[:, t] = rec.tau[:, t + 1] = (
                        plant.ctrl
                    )  # (the last instant keeps the last step's)
                plant.step()
                v_r = v_r + a_r * h
                q_r = q_r + v_r * h
                rec.physics_step(t + 1, plant, scene, q_r, lo, hi)
    return rec.result(plant, task, timing, h, system, time.perf_counter() - t_start)
