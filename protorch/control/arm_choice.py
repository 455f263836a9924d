"""The arm's online decision, shared by the kinematic test (:mod:`protorch.control.arm`) and the
physics test (:mod:`protorch.control.physics`): at every control step the moves of that instant, the
map's answer for every class at the current environments, and the class choice with hysteresis
from where the arm is now (:class:`ArmClassChoice`); and the joint-velocity command that turns
the chosen mean into a motion within the joint velocity and acceleration limits
(:func:`velocity_command_acceleration`). What these do is described in
:mod:`protorch.control.arm`.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from ..tasks.arm.collision import capsule_ends, capsules_clear, capsules_gap
from .episodes import basis_derivative_at
from .plan_memo import ClearanceMemo

__all__ = [
    "ArmClassChoice",
    "Follow",
    "hysteresis_choice",
    "rest_scores",
    "rest_plan",
    "rest_blocked",
    "rest_clearance",
    "checked_choice",
    "draw_moves",
    "apply_moves",
    "velocity_command_acceleration",
]

_BRIDGE = torch.linspace(0.0, 1.0, 9, dtype=torch.float64)[
    :-1
]  # (8,) from the arm to a class's path


def velocity_command_acceleration(
    q: Tensor,
    qd: Tensor,
    m: Tensor,
    m_vel: Tensor,
    *,
    kp: float,
    vmax: Tensor,
    amax: Tensor,
    dt: float,
) -> Tensor:
    """The acceleration ``(E, J)`` that reaches the commanded velocity ``m' + kp (m - q)`` (clamped
    to ``+-vmax``) in one step of ``dt`` within ``+-amax``, at the state ``q, qd (E, J)`` with
    the marker ``m`` moving at ``m_vel`` (``(E, J)``)."""
    v_cmd = torch.maximum(torch.minimum(m_vel + kp * (m - q), vmax), -vmax)  # (E, J)
    return torch.maximum(torch.minimum((v_cmd - qd) / dt, amax), -amax)  # (E, J)


def rest_scores(
    task,
    promp,
    means: Tensor,
    env: Tensor,
    ee_now: Tensor,
    rest: Tensor,
    path: Tensor | None = None,
) -> Tensor:
    """Summed objectives of the rest of the motion for every class: the way from the end effector
    now (``ee_now (E, 3)``) over to the class's mean path, then that path at the phases ``rest
    (P',)``; ``means (K, E, N)`` -> ``(K, E)``. ``path (K, E, P', 3)``: that mean path's end
    effector at ``rest`` when the caller has it already (computed from ``means`` otherwise)."""
    k, n_env = means.shape[:2]
    start = ee_now.expand(k, n_env, 3)  # (K, E, 3)
    if rest.numel():
        if path is None:
            path = task.ee_path(promp.trajectory(means, phase=rest))  # (K, E, P', 3)
        # the way over, sampled densely: a switch must not cross the can
        bridge = start[..., None, :] + _BRIDGE.to(path)[:, None] * (
            path[..., :1, :] - start[..., None, :]
        )
        path = torch.cat([bridge, path], -2)  # (K, E, 8 + P', 3)
    else:
        path = start[..., None, :]  # (K, E, 1, 3)
    return task.path_costs(path, env.expand(k, n_env, 4), start=start).sum(-1)  # (K, E)


class Follow(NamedTuple):
    """How the moving tests drive the arm towards the tracked mean (the velocity command of
    :func:`velocity_command_acceleration` integrated by :func:`~protorch.control.episodes.track`),
    for :func:`rest_plan` to roll it out: gain ``kp`` (1/s), limits ``vmax``, ``amax`` ``(J,)``,
    control step ``dt`` and the motion's ``duration`` (s)."""

    kp: float
    vmax: Tensor
    amax: Tensor
    dt: float
    duration: float
    tables: dict | None = (
        None  # rest_plan's basis values per phase, kept for the next plans (a policy's)
    )

    @property
    def horizon(self) -> int:
        """Control steps rolled out: five time constants ``1 / kp`` of the velocity loop, by when
        the arm has caught up with the mean it tracks."""
        return max(1, math.ceil(5.0 / (self.kp * self.dt) - 1e-9))


def rest_plan(
    promp,
    means: Tensor,
    now: Tensor,
    z: float,
    rest: Tensor,
    qd: Tensor | None = None,
    follow: Follow | None = None,
) -> Tensor:
    """Each class's plan for the rest of the motion as joints ``(K, E, P, J)``: from the arm's
    joints ``now`` (``(E, J)``, or ``(K, E, J)``) over to the class's mean ``means (K, E, N)``,
    then along that mean at the phases ``rest (P',)``. The way over: with ``follow`` and the arm's
    velocities ``qd`` (same shape as ``now``), the path the moving tests' velocity command drives
    from that state (:class:`Follow`: rolled out for ``follow.horizon`` control steps, every other
    step kept, the environment as it is now), then the mean at the phases of ``rest`` after the
    rollout; without them a straight line in joint space to the mean at ``z`` (8 points), then
    the mean at ``z`` and at ``rest``."""
    k, n_env = means.shape[:2]
    j = promp.num_dof
    now = now.to(means).expand(k, n_env, j)  # (K, E, J)
    if follow is None or qd is None:
        phases = torch.cat([rest.new_tensor([z]), rest])  # (1 + P',)
        traj = promp.trajectory(means, phase=phases)  # (K, E, 1 + P', J)
        bridge = now[..., None, :] + _BRIDGE.to(traj)[:, None] * (
            traj[..., :1, :] - now[..., None, :]
        )  # (K, E, 8, J)
        return torch.cat([bridge, traj], -2)  # (K, E, 9 + P', J)
    x, v = now.reshape(-1, j), qd.to(means).expand(k, n_env, j).reshape(-1, j)  # (K E, J)
    steps = follow.horizon
    basis, dbasis, later, phi_later = _plan_tables(promp, z, rest, follow, means)
    wk = means.reshape(-1, j, promp.num_basis)  # (K E, J, Kb)
    marks = wk @ basis  # (K E, J, H) the mean at each step (promp_state_at's)
    vels = wk @ dbasis  # (K E, J, H)
    vmax, amax = follow.vmax.to(x), follow.amax.to(x)
    if x.shape[0] <= FLOAT_ROWS and x.device.type == "cpu":  # a policy's decision: a few systems
        plan = _rollout_floats(x, v, marks, vels, follow, vmax, amax).reshape(
            k, n_env, -1, j
        )  # (K, E, S, J)
    else:
        path = [x]
        for i in range(steps):  # the semi-implicit Euler step of track()
            v = (
                v
                + velocity_command_acceleration(
                    x,
                    v,
                    marks[..., i],
                    vels[..., i],
                    kp=follow.kp,
                    vmax=vmax,
                    amax=amax,
                    dt=follow.dt,
                )
                * follow.dt
            )
            x = x + v * follow.dt
            if i % 2 == 0 or i == steps - 1:
                path.append(x)
        plan = torch.stack(path, 1).reshape(k, n_env, len(path), j)  # (K, E, S, J)
    if later.numel():  # the mean at the phases after the rollout, their basis from the tables
        plan = torch.cat([plan, promp.trajectory(means, basis=phi_later)], -2)  # (K, E, S + P'', J)
    return plan


def _plan_tables(promp, z: float, rest: Tensor, follow: Follow, like: Tensor) -> tuple:
    """:func:`rest_plan`'s basis values from ``z`` on: at the rollout's steps ``(Kb, H)`` and their
    time derivative ``(Kb, H)`` (none in the hold), the phases of ``rest`` after the rollout
    ``(P'',)`` and the basis there ``(P'', Kb)``; kept in ``follow.tables`` when it has one (a
    policy decides at the same phases motion after motion; the same numbers either way)."""
    key = (z, rest.shape[0], like.dtype, like.device)
    hit = None if follow.tables is None else follow.tables.get(key)
    if hit is None:
        steps = follow.horizon
        zs = [
            min(z + i * follow.dt / follow.duration, 1.0) for i in range(steps)
        ]  # the phases of the steps
        phase = torch.tensor(zs, dtype=like.dtype, device=like.device)  # (H,)
        moving = (phase < 1.0).to(like) / follow.duration  # (H,) no marker velocity in the hold
        dbasis = basis_derivative_at(promp, phase).to(like).T * moving  # (Kb, H)
        later = rest[
            rest > min(z + steps * follow.dt / follow.duration, 1.0)
        ]  # (P'',) the phases after the rollout
        hit = (
            promp.basis_at(phase).to(like).T,
            dbasis,
            later,
            promp.basis_at(later) if later.numel() else None,
        )
        if follow.tables is not None:
            if len(follow.tables) >= 1024:
                follow.tables.clear()
            follow.tables[key] = hit
    return hit


FLOAT_ROWS = (
    4  # rest_plan rolls out at most this many systems on Python floats (a policy's decision)
)


def _rollout_floats(
    x: Tensor, v: Tensor, marks: Tensor, vels: Tensor, follow: Follow, vmax: Tensor, amax: Tensor
) -> Tensor:
    """:func:`rest_plan`'s rollout for a few systems on Python floats: ``x, v (R, J)``, ``marks,
    vels (R, J, H)`` -> the kept positions ``(R, S, J)``. The same IEEE operations in the same order
    as the tensor loop (:func:`velocity_command_acceleration`, then the Euler step), so the same
    numbers to the bit for finite input; a few hundred operations on 7 numbers cost several
    times less as floats than as tensor operations."""
    kp, dt, steps = follow.kp, follow.dt, follow.horizon
    hv, ha = vmax.tolist(), amax.tolist()  # (J,)
    lv, la = [-h for h in hv], [-h for h in ha]
    out = []
    for xr, vr, mr, wr in zip(
        x.tolist(), v.tolist(), marks.transpose(1, 2).tolist(), vels.transpose(1, 2).tolist()
    ):
        path = [xr]
        for i in range(steps):
            c = [
                w + kp * (m - p) for w, m, p in zip(wr[i], mr[i], xr)
            ]  # the commanded velocity, then clamped
            c = [(h if a > h else (lo if a < lo else a)) for a, h, lo in zip(c, hv, lv)]
            g = [(a - b) / dt for a, b in zip(c, vr)]  # the acceleration, clamped below
            vr = [
                b + (h if a > h else (lo if a < lo else a)) * dt
                for a, b, h, lo in zip(g, vr, ha, la)
            ]
            xr = [p + b * dt for p, b in zip(xr, vr)]
            if i % 2 == 0 or i == steps - 1:
                path.append(xr)
        out.append(path)
    return torch.tensor(out, dtype=x.dtype)  # (R, S, J)


def rest_blocked(
    task,
    promp,
    means: Tensor,
    env: Tensor,
    now: Tensor,
    z: float,
    rest: Tensor,
    qd: Tensor | None = None,
    follow: Follow | None = None,
    extra: Tensor | None = None,
    memo: ClearanceMemo | None = None,
) -> Tensor:
    """Whether each class's plan for the rest of the motion (:func:`rest_plan`) touches the can,
    checked by the task's own :meth:`~protorch.tasks.ArmReachTask.can_gap` (its collision
    model) against ``margin``: ``means (K, E, N)``, ``env (E, 4)`` -> ``(K, E)`` bool (True:
    blocked). ``extra (K, E)``: metres added to ``margin`` per class and system (a class the arm
    does not track must clear by more: :func:`checked_choice`'s ``switch_clearance``). ``memo``
    (volumes only): plans that bounds carried from earlier checks show clear are passed without
    placing their capsules (the same verdict), and a full check's bounds are kept
    (:class:`~protorch.control.plan_memo.ClearanceMemo`)."""
    k, n_env = means.shape[:2]
    plan = rest_plan(promp, means, now, z, rest, qd, follow)  # (K, E, P, J)
    env = env.expand(k, n_env, env.shape[-1])  # (K, E, 4)
    margin = task.margin if extra is None else task.margin + extra.to(plan)  # a number | (K, E)
    if (
        getattr(task, "capsule_plan", None) is not None
    ):  # the volumes: the same verdict as can_gap, cheaper
        if memo is not None:
            flat = (
                plan.flatten(0, 1),
                env.flatten(0, 1),
                margin.flatten() if isinstance(margin, Tensor) else margin,
            )
            if memo.surely_clear(*flat):
                return torch.zeros(k, n_env, dtype=torch.bool, device=plan.device)
        a, b = capsule_ends(task.kinematics, plan, task.capsule_plan)  # (K, E, P, C, 3)
        clear = capsules_clear(
            a,
            b,
            task.capsule_radii.to(a),
            env,
            task.can_radius,
            task.can_height,
            margin,
            with_lower=memo is not None,
        )
        if memo is not None:
            clear, lower = clear  # (K, E), (K, E, P)
            memo.add(flat[0], flat[1], lower.flatten(0, 1))
        return ~clear
    return task.can_gap(plan, env) <= margin


def rest_clearance(
    task,
    promp,
    means: Tensor,
    env: Tensor,
    now: Tensor,
    z: float,
    rest: Tensor,
    qd: Tensor | None = None,
    follow: Follow | None = None,
) -> Tensor:
    """The smallest gap between the arm and the can along each class's plan (:func:`rest_plan`),
    the number :func:`rest_blocked` compares with ``margin``: ``(K, E)`` (metres)."""
    k, n_env = means.shape[:2]
    plan = rest_plan(promp, means, now, z, rest, qd, follow)  # (K, E, P, J)
    env = env.expand(k, n_env, env.shape[-1])  # (K, E, 4)
    if getattr(task, "capsule_plan", None) is not None:
        a, b = capsule_ends(task.kinematics, plan, task.capsule_plan)  # (K, E, P, C, 3)
        return capsules_gap(a, b, task.capsule_radii.to(a), env, task.can_radius, task.can_height)
    return task.can_gap(plan, env)


def hysteresis_choice(
    scores: Tensor, current: Tensor | None, switch_margin: float, blocked: Tensor | None = None
) -> Tensor:
    """The class each of ``E`` systems tracks, ``scores (K, E)`` -> ``(E,)`` indices into the
    ``K`` classes: the lowest score, where every class but the ``current (E,)`` one (``None``:
    none yet) pays ``switch_margin`` (hysteresis: two nearly equal classes would otherwise chatter).
    ``blocked (K, E)`` (:func:`rest_blocked`): a blocked class is chosen only where every class
    is blocked (then the scores alone decide)."""
    if blocked is not None:
        blocked = blocked & ~blocked.all(0)  # (K, E) where some class is clear
        scores = torch.where(blocked, torch.inf, scores)
    if current is not None:
        k = scores.shape[0]
        scores = scores + switch_margin * (
            torch.arange(k, device=scores.device)[:, None] != current.to(scores.device)
        )
    return scores.argmin(0)


def checked_choice(
    task,
    promp,
    means: Tensor,
    env: Tensor,
    now: Tensor,
    z: float,
    rest: Tensor,
    scores: Tensor,
    current: Tensor | None,
    switch_margin: float,
    qd: Tensor | None = None,
    follow: Follow | None = None,
    switch_clearance: float = 0.0,
    memo: ClearanceMemo | None = None,
) -> Tensor:
    """:func:`hysteresis_choice` with the plan check of :func:`rest_blocked`, checking only what
    can change the choice: each system's choice by the scores first, every class only where that
    class's plan is blocked (a clear choice stands whatever the other classes' plans, so this is
    the choice that checking every class gives); where every class is blocked, the class whose
    plan keeps the largest gap to the can (:func:`rest_clearance`). ``means (K, E, N)``, ``env
    (E, 4)``, ``now`` ``(E, J)`` (the arm) or ``(K, E, J)`` (per class), ``qd`` (the arm's
    velocities, as ``now``) and ``follow``: :func:`rest_plan`'s way over; ``scores (K, E)`` ->
    ``(E,)``.

    ``switch_clearance`` (metres) is the check's own hysteresis: a class other than the
    ``current`` one counts as clear only where its plan keeps ``margin + switch_clearance`` from
    the can, so a plan whose gap hovers at the margin (the can moving across the path) does not
    flip the choice back and forth between decisions. It never keeps a blocked plan: where no
    class passes that test, a class clear of ``margin`` alone is still taken (by the scores).
    Where every class is blocked, another class's gap must exceed the current one's by more than
    half of ``switch_clearance`` (the arm within the margin has near-equal gaps for every class,
    and the largest would flip with each step; the whole of it kept the arm on a plan heading
    into a sliding can in one of docs/control_loop.md's slides). ``current=None`` (the first
    decision) checks every class against ``margin`` alone. ``memo``: :func:`rest_blocked`'s (the
    same choice, fewer capsules placed)."""
    c = hysteresis_choice(scores, current, switch_margin)  # (E,)
    e = torch.arange(means.shape[1], device=means.device)
    per_class = now.dim() == 3
    other = None  # (K, E) 1.0 where a class is not the tracked one
    if current is not None and switch_clearance > 0:
        cur = current.to(means.device)
        other = (torch.arange(means.shape[0], device=means.device)[:, None] != cur).to(means.dtype)

    def part(x, i):
        return None if x is None else (x[:, i] if per_class else x[i])

    def check(m, en, q, v, o):  # rest_blocked on these means, systems, states, other's entries
        extra = None if o is None else switch_clearance * o
        return rest_blocked(task, promp, m, en, q, z, rest, v, follow, extra, memo)

    bad = check(
        means[c, e][None],
        env,
        now[c, e] if per_class else now,
        None if qd is None else (qd[c, e] if per_class else qd),
        None if other is None else other[c, e][None],
    )[0]  # (E,)
    if bool(bad.any()):
        i = torch.nonzero(bad).flatten()  # (n,) the systems whose choice is blocked
        blocked = check(
            means[:, i], env[i], part(now, i), part(qd, i), None if other is None else other[:, i]
        )  # (K, n)
        c = c.clone()
        c[i] = hysteresis_choice(
            scores[:, i], None if current is None else current[i], switch_margin, blocked
        )
        stuck = blocked.all(0)  # (n,) every class blocked: the largest clearance
        if bool(stuck.any()):
            s = i[stuck]
            gap = rest_clearance(
                task, promp, means[:, s], env[s], part(now, s), z, rest, part(qd, s), follow
            )  # (K, n')
            if other is None:
                c[s] = gap.argmax(0)
            # a class blocked only by the extra clearance, clear of the margin, goes first (by
            else:
                loose = (
                    gap > task.margin
                )  # (K, n') the scores); where none is, another class than the
                pick = hysteresis_choice(
                    scores[:, s], current[s], switch_margin, ~loose
                )  # (n',) tracked
                widest = (gap - 0.5 * switch_clearance * other[:, s]).argmax(
                    0
                )  # one only if wider by delta/2
                c[s] = torch.where(loose.any(0), pick, widest)
    return c


def draw_moves(
    num: int,
    moving: int,
    moves: Sequence[int],
    window: tuple[float, float],
    generator: torch.Generator | None,
) -> list[list[int]]:
    """Per episode, the sorted control steps at which something is moved."""
    lo, hi = window
    out = []
    counts = torch.tensor(list(moves))[
        torch.randint(len(moves), (num,), generator=generator)
    ]  # (E,)
    for c in counts.tolist():
        z = torch.sort(
            lo + (hi - lo) * torch.rand(int(c), generator=generator, dtype=torch.float64)
        ).values
        out.append(sorted({max(1, int(round(float(v) * moving))) for v in z}))
    return out


def apply_moves(
    task,
    envs: Tensor,
    q_now: Tensor,
    episodes: list[int],
    t: int,
    place_clearance: float,
    generator,
    moved: Tensor,
    tries: int = 64,
) -> None:
    """Move the can or the target of ``episodes`` from instant ``t`` on (in place), never onto the
    arm: the arm (under the task's collision model) stays more than ``place_clearance`` from the
    moved can's surface."""
    idx = torch.tensor(episodes)
    n = idx.numel()
    which = torch.rand(n, generator=generator) < 0.5  # True: the can, False: the target
    cand = task.sample_envs(n * tries, generator, dtype=envs.dtype, device=envs.device).reshape(
        n, tries, 4
    )
    old = envs[idx, t][:, None].expand(-1, tries, -1)  # (n, tries, 4)
    new = torch.where(
        which.to(envs.device)[:, None, None],
        torch.cat([cand[..., :2], old[..., 2:]], -1),
        torch.cat([old[..., :2], cand[..., 2:]], -1),
    )  # (n, tries, 4)
    frames = task.kinematics.frames(q_now[idx])[:, None, None]  # (n, 1, 1, F, 4, 4)
    clear = task.frames_gap(frames, new) > place_clearance  # (n, tries)
    ok = task.valid_envs(new) & clear  # (n, tries)
    for i, e in enumerate(episodes):
        good = torch.nonzero(ok[i]).flatten()
        if good.numel():
            envs[e, t:] = new[i, int(good[0])]
            moved[e] += 1


class ArmClassChoice:
    """The mean the arm tracks at each instant (module docstring of :mod:`protorch.control.arm`):
    ``answer(t, z, q, qd) -> (E, N)`` applies the moves scheduled for instant ``t`` (``schedule``,
    per
    episode, drawn with ``generator``; none for a prescribed walk), asks the map for every class
    at the current environments ``envs[:, t]`` (an unchanged environment reuses its last answer
    when ``reuse_answers``), scores each class on the rest of the motion from the end effector
    of ``q (E, J)`` and keeps the current class unless another one is better by more than
    ``switch_margin``; with ``check``, a class whose plan for the rest of the motion from ``q``
    touches the can (:func:`rest_blocked`; with ``follow`` and the arm's velocities ``qd`` the
    plan starts with the path the velocity command drives from that state, :func:`rest_plan`) is
    passed over while another class is clear, and where every class is blocked the one whose plan
    keeps the largest gap is taken (:func:`checked_choice`). Records ``labels (E, T+1)``,
    ``moved (E,)`` and ``queries``."""

    def __init__(
        self,
        task,
        env_map,
        promp,
        envs: Tensor,
        schedule: list[list[int]],
        total: int,
        *,
        place_clearance: float,
        switch_margin: float,
        generator,
        reuse_answers: bool,
        check: bool = False,
        follow: Follow | None = None,
        switch_clearance: float = 0.0,
    ) -> None:
        kw = dict(dtype=envs.dtype, device=envs.device)
        self.task, self.env_map, self.promp, self.envs = (
            task,
            env_map,
            promp,
            envs,
        )  # envs (E, T+1, 4)
        self.generator, self.reuse, self.check, self.follow = (
            generator,
            reuse_answers,
            bool(check),
            follow,
        )
        self.place_clearance, self.switch_margin = place_clearance, switch_margin
        self.switch_clearance = float(switch_clearance)
        self.cand = torch.unique(env_map.labels)  # (K,) the classes
        # phases the objectives of the rest of the motion are evaluated on
        self.grid = promp.phase[task.cost_indices(promp.num_steps)].to(**kw)  # (P,)
        n_env = envs.shape[0]
        self.by_step: dict[int, list[int]] = {}
        for e, steps in enumerate(schedule):
            for s in steps:
                self.by_step.setdefault(s, []).append(e)
        self.labels = torch.empty(
            n_env, total + 1, dtype=torch.long, device=envs.device
        )  # (E, T+1)
        self.moved = torch.zeros(n_env, dtype=torch.long)  # (E,)
        self.current = None  # (E,) index into cand of the tracked class
        self.means = torch.empty(
            self.cand.numel(), n_env, promp.num_weights, **kw
        )  # (K, E, N) answers for env_t
        self.answered = None  # (E, 4) the environments those answers are for
        self.queries = 0

    def answer(self, t: int, z: float, q: Tensor, qd: Tensor | None = None) -> Tensor:
        task, envs, n_env, k = self.task, self.envs, self.envs.shape[0], self.cand.numel()
        if t in self.by_step:
            apply_moves(
                task, envs, q, self.by_step[t], t, self.place_clearance, self.generator, self.moved
            )
        env_t = envs[:, t]  # (E, 4)
        # ---- the map's answer for every class at the current environments (Eq. 7)
        ask = (
            torch.ones(n_env, dtype=torch.bool, device=envs.device)
            if self.answered is None or not self.reuse
            else (env_t != self.answered).any(-1)
        )  # (E,) an unchanged environment has the same answer
        if bool(ask.any()):
            idx = torch.nonzero(ask).flatten()  # (n,)
            mu_q = self.env_map.predict_mean(
                env_t[idx].repeat(k, 1), self.cand.repeat_interleave(idx.numel())
            )
            self.means[:, idx] = mu_q.reshape(k, idx.numel(), -1).to(self.means)  # (K, n, N)
            self.answered = env_t.clone()
            self.queries += k * idx.numel()
        # ---- each class scored on the rest of the motion from where the arm is now
        q = q.to(self.means)
        rest = self.grid[self.grid > z]  # (P',)
        scores = rest_scores(
            task, self.promp, self.means, env_t, task.kinematics.ee_position(q), rest
        )  # (K, E)
        if self.check and k > 1:
            self.current = checked_choice(
                task,
                self.promp,
                self.means,
                env_t,
                q,
                z,
                rest,
                scores,
                self.current,
                self.switch_margin,
                None if qd is None else qd.to(self.means),
                self.follow,
                self.switch_clearance,
            )  # (E,)
        else:
            self.current = hysteresis_choice(scores, self.current, self.switch_margin)  # (E,)
        self.labels[:, t] = self.cand[self.current]
        return self.means[self.current, torch.arange(n_env, device=envs.device)]  # (E, N)
