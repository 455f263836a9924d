"""The two halves of a policy as programs (:meth:`~protorch.policy.policy.Policy.export` to a
folder): a planner program and a tracker program, each a ``torch.export`` graph with static
shapes that libtorch alone runs (AOTInductor packages with ``aoti=True``), the state each keeps
between calls passed in and handed back.

* :class:`PlannerProgram` ``(env (d,), t (), q (D,), qd (D,), current (), slot ()) -> (W (Kb, D),
  label (), current (), slot (), plan_t ())``: the planner's step of ``planner="thread"``
  (:meth:`~protorch.policy.policy.Policy.choose`): a class decision (every class's mean at
  ``env``, the scores of the rest of the motion from ``q``, the hysteresis and, with the run's
  ``check``, the plan check rolled out from ``q, qd``) where ``current < 0`` (no class yet) or
  ``t`` entered a new ``decision_dt`` slot after ``slot``; the tracked class's mean otherwise.
  ``current`` (the class row, int64, -1 before the first plan) and ``slot`` (int64) are its state.
  Each call solves every class's neighbour set afresh (the Python planner keeps and updates them:
  the same means to round-off).
* :class:`TrackerProgram` ``(t (), W (Kb, D), q (D,), qd (D,), W_last (Kb, D), t_last (), off (2,
  D), started ()) -> (q_r, qd_r, qdd_r (D,), W_last, t_last, off, started)``: the tracker's tick
  (:class:`~protorch.policy.two_rate.Tracker`): the plan's mean at ``t`` plus the continuity
  offset (the jump of the mean added where the plan changed; at the motion's first call,
  ``started = 0``, the gap from the measured ``q, qd``). The state at a motion's start: zeros.

The robot's limiter (:class:`~protorch.policy.limits.JointwiseLimiter`, on by default for the two
rates; :class:`~protorch.policy.limits.JerkLimiter` with ``limits="together"``) is not in the
tracker program: Ruckig is a C++ library (``ruckig::Ruckig``) that a C++ loop applies to the
tracker's output as the limiter does; the limits are written beside the programs
(``programs.json``'s ``limits``: ``null`` with ``limits=False``; ``synchronised``: one hand-over
of all joints, else one per joint).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch
from torch import Tensor

from ..control.arm_choice import rest_scores
from ..data.files import atomic_write_bytes
from .export import ExportProgram, save_program, static_gaps
from .limits import JerkLimiter
from .means import basis3

__all__ = ["PlannerProgram", "TrackerProgram", "tracker_state", "write_programs"]


def _hysteresis(scores: Tensor, current: Tensor, margin: float, blocked=None) -> Tensor:
    """:func:`~protorch.control.arm_choice.hysteresis_choice` for one system with the class
    ``current`` as a 0-d int64 tensor (< 0: none): ``scores (K,)`` -> ``()``."""
    if blocked is not None:
        scores = torch.where(blocked & ~blocked.all(), torch.inf, scores)
    k = scores.shape[0]
    other = (torch.arange(k) != current) & (current >= 0)  # (K,)
    return (scores + margin * other.to(scores.dtype)).argmin()


class PlannerProgram(ExportProgram):
    """The planner's step (module docstring)."""

    def __init__(self, policy) -> None:
        super().__init__(policy)
        p = policy
        if p.labels.numel() > 1 and p._arm and p.check and p._follow is None:
            raise ValueError(
                "exporting the plan check needs the moving test's velocity command (a robot with "
                "max_acceleration)"
            )

    def _grid(self) -> Tensor:
        """The objectives' phases ``(P,)`` (a buffer of :class:`ExportProgram`)."""
        grid = self.grid
        assert isinstance(grid, Tensor)
        return grid

    def _scores(self, means: Tensor, env: Tensor, z: Tensor, q: Tensor) -> Tensor:
        """Each class's score ``(K,)``: :meth:`~protorch.policy.choice.ClassChoice._scores` from
        the measured ``q``, for every count of the objectives' phases still ahead, the right one
        taken."""
        p, grid = self.p, self._grid()
        ee = p.task.ee_path(q[None])[None]  # (1, 1, 3)
        n = grid.shape[0]
        table = torch.stack(
            [
                rest_scores(p.task, p._P, means[:, None], env[None], ee, grid[n - r :])[:, 0]
                for r in range(n + 1)
            ]
        )  # (P + 1, K)
        return table[(grid > z).sum()]

    def _gaps(self, means: Tensor, env: Tensor, z: Tensor, q: Tensor, qd: Tensor) -> Tensor:
        """The smallest gap to the can along each class's plan for the rest of the motion from
        ``q, qd`` (:func:`~protorch.control.arm_choice.rest_plan` with the moving test's velocity
        command, then the mean at the objectives' phases after the rollout): ``(K,)``."""
        p, f = self.p, self.p._follow
        k, j, kb = means.shape[0], p._d, p._kb
        steps = f.horizon
        phase = torch.clamp(
            z + torch.arange(steps, dtype=torch.float64) * f.dt / f.duration, max=1.0
        )  # (H,) the rollout's phases, as rest_plan's
        b = p._P.basis_at(phase, order=1)  # (H, 2, Kb)
        moving = (phase < 1.0).to(torch.float64) / f.duration  # (H,)
        wk = means.view(k, j, kb)  # (K, J, Kb)
        marks = wk @ b[:, 0].T  # (K, J, H)
        vels = wk @ (b[:, 1].T * moving)  # (K, J, H)
        x, v = q.expand(k, j), qd.expand(k, j)  # (K, J)
        vmax, amax = f.vmax.to(x), f.amax.to(x)
        path = [x]
        for i in range(steps):  # rest_plan's semi-implicit Euler step, the same operations
            c = torch.maximum(torch.minimum(vels[..., i] + f.kp * (marks[..., i] - x), vmax), -vmax)
            a = torch.maximum(torch.minimum((c - v) / f.dt, amax), -amax)
            v = v + a * f.dt
            x = x + v * f.dt
            if i % 2 == 0 or i == steps - 1:
                path.append(x)
        roll = torch.stack(path, 1)  # (K, S, J)
        later = p._phi_grid @ wk.transpose(1, 2)  # (K, P, J) the mean at every phase of the grid
        after = torch.clamp(z + steps * f.dt / f.duration, max=1.0)
        gaps = static_gaps(
            p.task, torch.cat([roll, later], 1), env.expand(k, roll.shape[1] + later.shape[1], -1)
        )  # (K, S + P)
        keep = torch.cat([torch.ones(roll.shape[1], dtype=torch.bool), self._grid() > after])
        return torch.where(keep, gaps, torch.inf).amin(-1)  # (K,)

    def _decide(self, means, env, z, q, qd, current) -> Tensor:
        """A class decision (:meth:`~protorch.policy.choice.ClassChoice._decide` with ``q``):
        ``()``."""
        p = self.p
        if not p._arm:
            scores = p.task.costs(p._P.trajectory(means), env.expand(means.shape[0], -1)).sum(-1)
            return _hysteresis(scores, current, p.switch_margin)
        scores = self._scores(means, env, z, q)  # (K,)
        c0 = _hysteresis(scores, current, p.switch_margin)
        if not p.check:
            return c0
        k, sc, margin = means.shape[0], p.switch_clearance, p.task.margin
        other = ((torch.arange(k) != current) & (current >= 0)).to(torch.float64)  # (K,)
        gap = self._gaps(means, env, z, q, qd)  # (K,)
        blocked = gap <= margin + sc * other  # (K,) checked_choice's, every class checked
        pick = _hysteresis(scores, current, p.switch_margin, blocked)
        if sc > 0:
            loose = gap > margin
            stuck = torch.where(
                (current >= 0) & loose.any(),
                _hysteresis(scores, current, p.switch_margin, ~loose),
                torch.where(current >= 0, (gap - 0.5 * sc * other).argmax(), gap.argmax()),
            )
        else:
            stuck = gap.argmax()
        return torch.where(blocked[c0], torch.where(blocked.all(), stuck, pick), c0)

    def forward(self, env, t, q, qd, current, slot):  # type: ignore[override]
        p = self.p
        means = self._means(env)  # (K, N)
        slot_t = torch.floor(t / p.decision_dt + 1e-9).to(torch.long)  # ()
        if means.shape[0] == 1:
            c = torch.zeros((), dtype=torch.long)
            decide = torch.ones((), dtype=torch.bool)
        else:
            z = torch.clamp(t / p.duration, max=1.0)
            decide = (current < 0) | (slot_t > slot)
            c = torch.where(decide, self._decide(means, env, z, q, qd, current), current)
        W = means[c].view(p._d, p._kb).T.contiguous()  # (Kb, D), row-major (AOTInductor takes
        # its inputs' strides as traced: a transposed W would be read wrong by the tracker)
        # no output is an input (AOTInductor's outputs must be tensors of their own)
        return W, self.labels[c], c, torch.where(decide, slot_t, slot), t.clone()


class TrackerProgram(torch.nn.Module):
    """The tracker's tick (module docstring), without the robot's jerk limiter."""

    def __init__(self, policy) -> None:
        super().__init__()
        P = policy._P
        self.register_buffer("centers", P.centers.to(torch.float64).clone())
        self.width, self.duration, self.blend = float(P.width), policy.duration, policy.blend
        self.register_buffer(
            "scale",
            torch.tensor([1.0, 1.0 / self.duration, 1.0 / self.duration**2], dtype=torch.float64)[
                :, None
            ],
        )  # (3, 1)
        self.P = P

    def _decay(self, s: Tensor) -> Tensor:
        """:func:`~protorch.policy.means.decay_matrix` at a 0-d ``s``: ``(3, 2)``."""
        w, e = self.blend, torch.exp(-self.blend * s)
        return torch.stack(
            [
                torch.stack([(1 + w * s) * e, s * e]),
                torch.stack([-w * w * s * e, (1 - w * s) * e]),
                torch.stack([(-w * w + w**3 * s) * e, (-2 * w + w * w * s) * e]),
            ]
        )

    def forward(self, t, W, q, qd, W_last, t_last, off, started):
        z = torch.clamp(t / self.duration, max=1.0)
        phi = basis3(self.P, z) * self.scale  # (3, Kb)
        moving = (t < self.duration).to(torch.float64)
        phi = torch.cat([phi[:1], phi[1:] * moving])  # held at the end
        state = phi @ W  # (3, D)
        if not math.isfinite(self.blend):
            return (
                state[0],
                state[1],
                state[2],
                W.clone(),
                t.clone(),
                off.clone(),
                torch.ones_like(started),
            )
        jump = torch.where(
            started > 0, phi[:2] @ (W_last - W), torch.stack([q, qd]) - state[:2]
        )  # (2, D)
        off = self._decay(t - t_last)[:2] @ off + jump  # (2, D)
        state = state + self._decay(torch.zeros_like(t)) @ off
        # no output is an input (AOTInductor's outputs must be tensors of their own)
        return state[0], state[1], state[2], W.clone(), t.clone(), off, torch.ones_like(started)


def tracker_state(policy) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The tracker program's state at a motion's start: ``W_last (Kb, D)``, ``t_last ()``, ``off
    (2, D)``, ``started ()``, zeros."""
    z = torch.zeros((), dtype=torch.float64)
    return (
        torch.zeros(policy._kb, policy._d, dtype=torch.float64),
        z,
        torch.zeros(2, policy._d, dtype=torch.float64),
        z.clone(),
    )


def write_programs(policy, folder: Path, aoti: bool | str = False) -> Path:
    """:meth:`~protorch.policy.policy.Policy.export` to a folder: ``planner.pt2``,
    ``tracker.pt2`` and ``programs.json`` (the rates, the shapes, the labels, which program is an
    AOTInductor package and the robot's limits that a C++ loop's Ruckig applies). ``aoti``:
    ``True`` both compiled by AOTInductor, ``"tracker"`` the tracker only (an arm's planner takes
    minutes to compile), ``False`` neither."""
    if aoti not in (True, False, "tracker"):
        raise ValueError(f"aoti must be True, False or 'tracker', got {aoti!r}")
    folder.mkdir(parents=True, exist_ok=True)
    f64, i64 = torch.float64, torch.long
    env = policy.env_map.E[0].to(f64)
    t = torch.tensor(0.5 * policy.duration, dtype=f64)
    q = torch.zeros(policy._d, dtype=f64)
    planner = PlannerProgram(policy)
    save_program(
        planner,
        (env, t, q, q.clone(), torch.tensor(-1, dtype=i64), torch.tensor(0, dtype=i64)),
        folder / "planner.pt2",
        aoti is True,
        f"the {type(planner).__name__}",
    )
    W = torch.zeros(policy._kb, policy._d, dtype=f64)
    args = (t.clone(), W, q.clone(), q.clone(), *tracker_state(policy))  # no input aliases another
    tracker = TrackerProgram(policy)
    save_program(tracker, args, folder / "tracker.pt2", bool(aoti), f"the {type(tracker).__name__}")
    lim = policy._halves_limiter  # the two-rate policy's (an inline policy's: what thread gets)
    meta = {
        "aoti": {"planner": aoti is True, "tracker": bool(aoti)},
        "env_dim": policy.env_dim,
        "dof": policy._d,
        "num_basis": policy._kb,
        "duration": policy.duration,
        "decision_dt": policy.decision_dt,
        "tick": 1e-3,
        "labels": policy.labels.tolist(),
        "limits": None
        if lim is None
        else {
            "max_velocity": lim.vmax.tolist(),
            "max_acceleration": lim.amax.tolist(),
            "max_jerk": lim.jmax.tolist(),
            "synchronised": isinstance(lim, JerkLimiter),  # one hand-over of all joints, or each
        },
    }
    atomic_write_bytes(folder / "programs.json", json.dumps(meta, indent=1).encode())
    return folder
