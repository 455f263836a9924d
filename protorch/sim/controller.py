"""The inverse-dynamics (computed-torque) controller, vectorised over episodes.

For ``E`` arms at ``q, qd (E, J)`` tracking references ``q_r, v_r, a_r (E, J)``:

    ``tau = M(q) (a_r + kp (q_r - q) + kd (v_r - qd)) + c(q, qd) - f_passive(qd)``,

with ``M`` the joint-space inertia matrix, ``c`` the Coriolis, centrifugal and gravity forces
(MuJoCo's ``qfrc_bias``) and ``f_passive`` the joint damping (``qfrc_passive``), all of the
*controller's* model (:func:`~protorch.sim.scene.controller_model`, masses possibly scaled): with
a correct model the arm's joint errors obey ``e'' + kd e' + kp e = 0``. The torque is the
inverse dynamics ``mj_inverse`` computes for the acceleration in brackets (checked in
``tests/sim/test_controller.py``); it is then clipped to the torque limits, and an episode whose
command exceeded a limit is counted *saturated* (:mod:`protorch.control.physics`). With a
torque-feasible reference (:meth:`ComputedTorque.feasible_torques`, ``physics.feasible``) the
reference's acceleration is first scaled down so that the command stays within a fraction of the
limits: the reference slows where the motors cannot follow it.

One ``mujoco.batch.Batch`` of the controller's model holds the ``E`` arms: each call loads their
states, computes the position and velocity stages on a thread pool and reads ``M`` (sparse rows,
scattered into ``(E, J, J)``), the bias and the passive forces in bulk.

Stability: MuJoCo's semi-implicit Euler step with the reference integrated the same way maps
the joint error as the PD step of :func:`protorch.control.episodes.check_pd_stable` with unit
mass, so gains with ``kp h^2 + 2 kd h >= 4`` (``h`` the timestep) are refused before any work.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..checks import check_number
from ..control.episodes import check_pd_stable
from .mj import load_mujoco

__all__ = ["ComputedTorque", "check_gains", "dense_mass"]


def check_gains(kp: float, kd: float, timestep: float) -> tuple[float, float]:
    """``kp > 0``, ``kd >= 0``, stable at ``timestep`` (module docstring); a clear
    error otherwise."""
    kp, kd = check_number(kp, "physics.kp"), check_number(kd, "physics.kd", allow_zero=True)
    try:
        check_pd_stable(kp, kd, 1.0, timestep)
    except ValueError as exc:
        raise ValueError(f"physics gains: {exc}") from None
    return kp, kd


def dense_mass(model, sparse: np.ndarray) -> np.ndarray:
    """MuJoCo's sparse inertia matrices ``(E, nM)`` (``MjData.M`` per episode: the lower triangle's
    rows) as dense symmetric ``(E, nv, nv)``."""
    rows = np.repeat(np.arange(model.nv), model.M_rownnz)
    cols = np.asarray(model.M_colind)
    out = np.zeros((sparse.shape[0], model.nv, model.nv))
    out[:, rows, cols] = sparse
    out[:, cols, rows] = sparse
    return out


class ComputedTorque:
    """``E`` computed-torque controllers on the controller's ``model`` (module docstring).

    Args:
        model: the controller's MuJoCo model (:func:`~protorch.sim.scene.controller_model`).
        num: ``E``, the arms controlled at once.
        kp, kd: joint-error gains (1/s^2, 1/s), the same for every joint.
        threads: the thread pool of the controller's batch.
    """

    def __init__(self, model, num: int, *, kp: float, kd: float, threads: int = 1) -> None:
        mujoco = load_mujoco()
        self.kp, self.kd = check_gains(kp, kd, model.opt.timestep)
        self.model = model
        self.batch = mujoco.batch.Batch(model, int(num), nthread=int(threads))
        self._qpos, self._qvel = (
            self.batch.bind("qpos"),
            self.batch.bind("qvel"),
        )  # (E, J) views of the state
        self._m, self._bias = self.batch.bind("M"), self.batch.bind("qfrc_bias")
        self._passive = self.batch.bind("qfrc_passive")
        self._stage = int(mujoco.mjtStage.mjSTAGE_VEL)

    def dynamics(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``M (E, J, J)`` and ``bias - passive (E, J)`` of the controller's model at ``q, qd (E,
        J)``."""
        self._qpos[:] = q
        self._qvel[:] = qd
        self.batch.forward(stage=self._stage)
        return dense_mass(self.model, self._m), self._bias - self._passive

    def _state(self, q: np.ndarray, qd: np.ndarray) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``M (E, J, J)``, ``bias - passive (E, J)`` and the measured ``q, qd (E, J)``
        as tensors."""
        mass, rest = self.dynamics(q, qd)  # (E, J, J), (E, J)
        qt, qdt = (
            torch.from_numpy(np.ascontiguousarray(q)),
            torch.from_numpy(np.ascontiguousarray(qd)),
        )
        return torch.from_numpy(mass), torch.from_numpy(rest), qt, qdt

    def torques(
        self, q: np.ndarray, qd: np.ndarray, q_r: Tensor, v_r: Tensor, a_r: Tensor
    ) -> Tensor:
        """The commanded torques ``(E, J)`` (float64, not yet clipped) at the measured state
        ``q, qd (E, J)`` for the references ``q_r, v_r, a_r (E, J)``."""
        mass, rest, qt, qdt = self._state(q, qd)
        u = (
            a_r + self.kp * (q_r - qt) + self.kd * (v_r - qdt)
        )  # (E, J) the commanded joint acceleration
        return torch.einsum("eij,ej->ei", mass, u) + rest  # (E, J)

    def feasible_torques(
        self, q: np.ndarray, qd: np.ndarray, q_r: Tensor, v_r: Tensor, a_r: Tensor, bound: Tensor
    ) -> tuple[Tensor, Tensor]:
        """:meth:`torques` with the reference's acceleration scaled down, per episode, so that
        every torque stays within ``bound (J,)`` where it can: ``a_r`` times the largest ``s`` in
        ``[0, 1]`` with ``|base + s M a_r| <= bound`` (``base``: the feedback, bias and damping
        torques; ``s = 1`` where the command is within the bound, and where no ``s`` is: the
        feedback and gravity alone pass it, the plain command is sent, clipped and counted).
        The reference integrates the scaled acceleration, so it slows down where the motors could
        not follow it (a torque-feasible time scaling of the plan) instead of commanding torques a
        real Panda's reflex would stop. Returns ``(torques (E, J), scaled a_r (E, J))``."""
        mass, rest, qt, qdt = self._state(q, qd)
        fb = self.kp * (q_r - qt) + self.kd * (
            v_r - qdt
        )  # (E, J) the feedback's joint acceleration
        base = (
            torch.einsum("eij,ej->ei", mass, fb) + rest
        )  # (E, J) the torques without the reference's acceleration
        ff = torch.einsum("eij,ej->ei", mass, a_r)  # (E, J) the reference acceleration's own part
        # per joint, the s with -bound <= base + s ff <= bound: an interval [lo, hi] (all s where ff
        # = 0 and
        # |base| <= bound, none where ff = 0 and |base| > bound)
        a, b = (-bound - base) / ff, (bound - base) / ff  # (E, J); where ff = 0 neither is used
        lo = torch.where(
            ff > 0,
            a,
            torch.where(ff < 0, b, torch.where(base.abs() <= bound, -torch.inf, torch.inf)),
        )
        hi = torch.where(
            ff > 0,
            b,
            torch.where(ff < 0, a, torch.where(base.abs() <= bound, torch.inf, -torch.inf)),
        )
        lo, hi = lo.amax(-1).clamp_min(0.0), hi.amin(-1).clamp_max(1.0)  # (E,)
        s = torch.where(
            lo <= hi, hi, torch.ones_like(hi)
        )  # (E,) the largest feasible scale, else the plain command
        s = torch.nan_to_num(s, nan=1.0)[
            :, None
        ]  # (E, 1) a non-finite command stays as it is, and fails
        return base + s * ff, s * a_r
