"""The online test of the paper's Fig. 7: the arm reaches while a person moves the can or the
target, and it switches between passing the can on the left and on the right on the fly.

At every control step the environment map is queried once for all ``E`` episodes and every
label (homotopy class) at their current environments; each class's predicted mean is scored by
the task's objectives on *the rest of the motion from where the arm is now* (the end effector
now, then the class's mean end-effector path from the current phase to the end:
:meth:`~protorch.tasks.ArmReachTask.path_costs` with the current position as start, summed), and
the arm keeps its class unless another one scores lower by more than ``switch_margin``
(hysteresis: two nearly equal classes, a can right on the straight line, would otherwise chatter).
This is the label-aware inference of the self-improvement loop
(:meth:`~protorch.gp.EnvMap.predict_best`) with the current state as the start of the objectives.
An environment that did not change since the last step gets the map's last answer again
(``reuse_answers``): the map is a pure function of the environment, and this makes the
per-step query cost that of the scoring alone between moves.

The arm tracks the chosen mean joint trajectory at the current phase ``z = min(t dt / duration, 1)``
(the "marker", as in :mod:`protorch.control.particle`): the commanded joint velocity is the marker's
velocity plus ``kp`` times the joint error, clamped to the joint velocity limits, and reached
with at most the joint acceleration limits (``v += clamp((v_cmd - v) / dt, -a_max, a_max) dt;
q += v dt``). After ``duration`` the marker rests at the mean's end for ``hold`` seconds.

Moves: each episode gets 1 or 2 (``moves``) moves at random phases in ``move_window``; a move
puts either the can or the target (equally likely) at a new random position of the task's
sampler (can and target keeping their separation), as a person would: never onto the arm, i.e.
at least ``place_clearance`` beyond the can radius from the arm's skeleton at that instant.
The person moves things at once (a jump), which is the hardest case for the controller.

Success over the whole episode, at every instant with the environment of that instant: no
skeleton segment within ``can_radius + margin`` of the can's axis, every joint inside its limits,
nothing below the table, and, after the hold, the end effector within ``goal_tol`` of the final
target. The arm starts at rest at the task's start configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import torch
from torch import Tensor

from ..checks import check_number, check_tensor
from ..robots.panda import PANDA_MAX_ACCELERATION
from .episodes import (
    Timing,
    check_timing,
    check_velocity_loop_stable,
    episode_walk,
    hold_last,
    track,
)

__all__ = ["ArmEpisodeResult", "run_arm_episodes", "count_switches", "rest_scores"]

_BRIDGE = torch.linspace(0.0, 1.0, 9, dtype=torch.float64)[:-1]  # (8,) from the arm to a class's path


def count_switches(labels: Tensor) -> Tensor:
    """Changes of the tracked class per episode: ``labels (E, T+1) -> (E,)`` long."""
    return (labels[:, 1:] != labels[:, :-1]).sum(-1)


@dataclass
class ArmEpisodeResult:
    """``E`` simulated episodes of ``T`` control steps (``T + 1`` instants ``t dt``)."""

    q: Tensor  # (E, T+1, J) joint positions
    qd: Tensor  # (E, T+1, J) joint velocities
    envs: Tensor  # (E, T+1, 4) the environment at each instant
    labels: Tensor  # (E, T+1) long: the class tracked at each instant
    weights: Tensor | None  # (E, T+1, N) the tracked class's predicted mean (record=True)
    success: Tensor  # (E,) bool
    collided: Tensor  # (E,) bool
    within_limits: Tensor  # (E,) bool
    final_goal_distance: Tensor  # (E,)
    min_can_distance: Tensor  # (E,) skeleton to can axis, over the episode
    moves: Tensor  # (E,) long, moves that happened
    map_queries: int  # (environment, class) answers the map computed; unchanged environments reuse theirs
    dt: float
    duration: float
    hold: float
    num_moving_steps: int
    promp: Any = field(default=None, repr=False)
    task: Any = field(default=None, repr=False)

    @property
    def num_episodes(self) -> int:
        return self.q.shape[0]

    @property
    def switches(self) -> Tensor:
        """``(E,)`` changes of the tracked class."""
        return count_switches(self.labels)

    @property
    def success_rate(self) -> float:
        return float(self.success.double().mean())

    def summary(self) -> dict:
        """JSON-able numbers: success, switches, collisions, goal distances."""
        sw = self.switches
        switched = sw > 0
        d = self.final_goal_distance
        return {
            "episodes": self.num_episodes,
            "success_rate": self.success_rate,
            "switches": int(sw.sum()),
            "episodes_with_switch": int(switched.sum()),
            "success_rate_with_switch": float(self.success[switched].double().mean()) if bool(switched.any())
            else float("nan"),
            "moves": int(self.moves.sum()),
            "map_queries": self.map_queries,
            "collision_rate": float(self.collided.double().mean()),
            "limit_violation_rate": float((~self.within_limits).double().mean()),
            "final_goal_distance_median": float(d.median()),
            "goal_reached_rate": float((d <= self.task.goal_tol).double().mean()) if self.task is not None
            else float("nan"),
        }

    def episode(self, i: int) -> dict:
        """Numpy arrays of episode ``i`` for :mod:`protorch.viz.arm`: ``links (T+1, F, 3)`` the arm's
        skeleton, ``ee (T+1, 3)``, ``means (T+1, P, 3)`` the end-effector path of the tracked
        mean at each instant (needs ``record=True``), ``envs (T+1, 4)``, ``labels (T+1,)``,
        ``dt``, ``success``."""
        if not -self.num_episodes <= i < self.num_episodes:
            raise IndexError(f"episode {i} out of range for {self.num_episodes} episodes")
        if self.weights is None:
            raise ValueError("this result was run with record=False: no mean trajectories to plot")
        with torch.no_grad():
            links = self.task.kinematics.link_positions(self.q[i])  # (T+1, F, 3)
            means = self.task.ee_path(self.promp.trajectory(self.weights[i]))  # (T+1, P, 3)

        def np_(x):
            return x.detach().cpu().numpy()

        return {"links": np_(links), "ee": np_(links[:, -1]), "means": np_(means), "envs": np_(self.envs[i]),
                "labels": np_(self.labels[i]), "dt": self.dt, "success": bool(self.success[i])}


def _draw_moves(num: int, moving: int, moves: Sequence[int], window: tuple[float, float],
                generator: torch.Generator | None) -> list[list[int]]:
    """Per episode, the sorted control steps at which something is moved."""
    lo, hi = window
    out = []
    counts = torch.tensor(list(moves))[torch.randint(len(moves), (num,), generator=generator)]  # (E,)
    for c in counts.tolist():
        z = torch.sort(lo + (hi - lo) * torch.rand(int(c), generator=generator, dtype=torch.float64)).values
        out.append(sorted({max(1, int(round(float(v) * moving))) for v in z}))
    return out


def run_arm_episodes(
    model,
    task,
    env0: Tensor | None = None,
    *,
    walk: Tensor | None = None,
    duration: float = 3.0,
    hold: float = 1.0,
    dt: float = 0.02,
    kp: float = 10.0,
    max_acceleration: Sequence[float] = PANDA_MAX_ACCELERATION,
    moves: Sequence[int] = (1, 2),
    move_window: tuple[float, float] = (0.1, 0.6),
    place_clearance: float = 0.05,
    switch_margin: float = 0.02,
    generator: torch.Generator | None = None,
    reuse_answers: bool = True,
    record: bool = True,
) -> ArmEpisodeResult:
    """Simulate ``E`` moving-environment episodes at once (module docstring).

    Args:
        model: ``model.env_map`` (an :class:`~protorch.gp.EnvMap`, asked every step for every
            label's mean) and ``model.promp``, e.g.
            :func:`protorch.load`'s :class:`~protorch.data.checkpoint.EnvToProMP`.
        task: an :class:`~protorch.tasks.ArmReachTask`.
        env0: ``(E, 4)`` initial environments; the moves are drawn with ``generator``. Or
            ``walk``: ``(E, M + 1, 4)`` prescribed environments of the ``M = ceil(duration / dt)``
            moving steps (frozen for the hold), no random moves.
        duration, hold, dt: seconds of motion, of holding the end, control step.
        kp: gain of the joint-position error in the commanded velocity (1/s); refused unless
            ``kp dt < 2`` (the one-step velocity command is stable only then, derived in
            :mod:`protorch.control.episodes`; the defaults give 0.2). An episode has at most
            :data:`~protorch.control.episodes.MAX_STEPS` (``10^6``) control steps.
        max_acceleration: per joint (rad/s^2); the velocity limits are the URDF's.
        moves, move_window, place_clearance: how many moves an episode gets (one value drawn
            uniformly from ``moves``), in which phase range, and how far from the arm a moved
            can stays (beyond its radius).
        switch_margin: hysteresis of the class choice, in units of the summed objectives.
        reuse_answers: the map is asked every control step, but an environment that did not
            change since the last step gets its last answer again (the map is a pure function
            of it) instead of a new GP solve; ``False`` solves every step (same result, slower).
        record: keep the tracked mean weights of every instant (for figures).
    """
    env_map, promp = getattr(model, "env_map", None), getattr(model, "promp", None)
    if env_map is None or not callable(getattr(env_map, "predict_mean", None)) or promp is None:
        raise ValueError("model must have .env_map (a protorch EnvMap) and .promp, e.g. protorch.load(run_dir)")
    if promp.num_dof != task.num_dof:
        raise ValueError(f"the ProMP has {promp.num_dof} DoF but the arm has {task.num_dof} joints")
    timing = check_timing(dt, duration, hold)
    kp = check_number(kp, "kp")
    check_velocity_loop_stable(kp, timing.dt)
    place_clearance = check_number(place_clearance, "place_clearance", allow_zero=True)
    switch_margin = check_number(switch_margin, "switch_margin", allow_zero=True)
    moves = [int(m) for m in moves]
    if not moves or min(moves) < 0:
        raise ValueError(f"moves must be a non-empty list of ints >= 0, got {moves}")
    lo_w, hi_w = (float(v) for v in move_window)
    if not 0 <= lo_w <= hi_w <= 1:
        raise ValueError(f"move_window must be (lo, hi) with 0 <= lo <= hi <= 1, got {move_window}")
    kw = dict(dtype=promp.basis.dtype, device=promp.basis.device)
    walk = episode_walk(env0, walk, timing, 4)
    if walk is not None:
        envs = hold_last(task.check_envs(walk, "walk").to(**kw), timing.held)  # (E, T+1, 4)
        schedule = [[] for _ in range(walk.shape[0])]
    else:
        env0 = task.check_envs(check_tensor(env0, "env0", ndim=2), "env0").to(**kw)
        if env0.shape[0] < 1:
            raise ValueError(f"env0 holds no environment: shape {tuple(env0.shape)}")
        envs = env0[:, None].repeat(1, timing.total + 1, 1)  # (E, T+1, 4), rewritten by the moves
        schedule = _draw_moves(env0.shape[0], timing.moving, moves, (lo_w, hi_w), generator)
    arm = _ArmTracker(task, env_map, promp, envs, schedule, timing, kp=kp, max_acceleration=max_acceleration,
                      place_clearance=place_clearance, switch_margin=switch_margin, generator=generator,
                      reuse_answers=reuse_answers)
    run = track(arm, promp, timing, envs.shape[0], task.start_config(**kw), record=record, markers=False)
    q = run.positions  # (E, T+1, J)
    with torch.no_grad():
        kin = task.kinematics
        links = kin.link_positions(q)  # (E, T+1, F, 3)
        dist = task.skeleton_distance(links[:, :, None], envs)  # (E, T+1)
        min_dist = dist.amin(-1)
        collided = min_dist <= task.can_radius + task.margin
        limits = kin.within_limits(q).all(-1)
        table = (links[..., 1:, 2] >= 0).flatten(1).all(-1)
        goal = (links[:, -1, -1] - task.goal_point(envs[:, -1])).norm(dim=-1)
        success = ~collided & limits & table & (goal <= task.goal_tol)
    return ArmEpisodeResult(q=q, qd=run.velocities, envs=envs, labels=arm.labels, weights=run.weights,
                            success=success, collided=collided, within_limits=limits, final_goal_distance=goal,
                            min_can_distance=min_dist, moves=arm.moved, map_queries=arm.queries, dt=timing.dt,
                            duration=timing.duration, hold=timing.hold, num_moving_steps=timing.moving,
                            promp=promp, task=task)


class _ArmTracker:
    """The arm for :func:`~protorch.control.episodes.track`: at each instant the moves of that
    instant, every class's answer for the current environments (reused where unchanged), the class
    choice with hysteresis; a velocity command within the joint velocity and acceleration limits."""

    def __init__(self, task, env_map, promp, envs: Tensor, schedule: list[list[int]], timing: Timing, *,
                 kp: float, max_acceleration, place_clearance: float, switch_margin: float, generator,
                 reuse_answers: bool) -> None:
        kw = dict(dtype=envs.dtype, device=envs.device)
        self.task, self.env_map, self.promp, self.envs = task, env_map, promp, envs  # envs (E, T+1, 4)
        self.dt, self.kp, self.generator, self.reuse = timing.dt, kp, generator, reuse_answers
        self.place_clearance, self.switch_margin = place_clearance, switch_margin
        self.vmax = task.kinematics.max_velocity.to(**kw)  # (J,)
        self.amax = torch.as_tensor(max_acceleration, **kw).expand(task.num_dof)  # (J,)
        self.cand = torch.unique(env_map.labels)  # (K,) the classes
        # phases the objectives of the rest of the motion are evaluated on
        self.grid = promp.phase[task.cost_indices(promp.num_steps)].to(**kw)  # (P,)
        n_env = envs.shape[0]
        self.by_step: dict[int, list[int]] = {}
        for e, steps in enumerate(schedule):
            for s in steps:
                self.by_step.setdefault(s, []).append(e)
        self.labels = torch.empty(n_env, timing.total + 1, dtype=torch.long, device=envs.device)  # (E, T+1)
        self.moved = torch.zeros(n_env, dtype=torch.long)  # (E,)
        self.current = None  # (E,) index into cand of the tracked class
        self.means = torch.empty(self.cand.numel(), n_env, promp.num_weights, **kw)  # (K, E, N) answers for env_t
        self.answered = None  # (E, 4) the environments those answers are for
        self.queries = 0

    def answer(self, t: int, z: float, q: Tensor) -> Tensor:
        task, envs, n_env, k = self.task, self.envs, self.envs.shape[0], self.cand.numel()
        if t in self.by_step:
            _apply_moves(task, envs, q, self.by_step[t], t, self.place_clearance, self.generator, self.moved)
        env_t = envs[:, t]  # (E, 4)
        # ---- the map's answer for every class at the current environments (Eq. 7)
        ask = torch.ones(n_env, dtype=torch.bool, device=envs.device) if self.answered is None or not self.reuse \
            else (env_t != self.answered).any(-1)  # (E,) an unchanged environment has the same answer
        if bool(ask.any()):
            idx = torch.nonzero(ask).flatten()  # (n,)
            mu_q = self.env_map.predict_mean(env_t[idx].repeat(k, 1), self.cand.repeat_interleave(idx.numel()))
            self.means[:, idx] = mu_q.reshape(k, idx.numel(), -1).to(self.means)  # (K, n, N)
            self.answered = env_t.clone()
            self.queries += k * idx.numel()
        # ---- each class scored on the rest of the motion from where the arm is now
        ee = task.kinematics.ee_position(q)  # (E, 3)
        scores = rest_scores(task, self.promp, self.means, env_t, ee, self.grid[self.grid > z])  # (K, E)
        if self.current is not None:  # hysteresis: every other class pays the margin
            scores = scores + self.switch_margin * (torch.arange(k, device=scores.device)[:, None] != self.current)
        self.current = scores.argmin(0)  # (E,)
        self.labels[:, t] = self.cand[self.current]
        return self.means[self.current, torch.arange(n_env, device=envs.device)]  # (E, N)

    def acceleration(self, q: Tensor, qd: Tensor, m: Tensor, m_vel: Tensor) -> Tensor:
        v_cmd = torch.maximum(torch.minimum(m_vel + self.kp * (m - q), self.vmax), -self.vmax)  # (E, J)
        return torch.maximum(torch.minimum((v_cmd - qd) / self.dt, self.amax), -self.amax)  # (E, J)


def rest_scores(task, promp, means: Tensor, env: Tensor, ee_now: Tensor, rest: Tensor) -> Tensor:
    """Summed objectives of the rest of the motion for every class: the way from the end effector
    now (``ee_now (E, 3)``) over to the class's mean path, then that path at the phases ``rest
    (P',)``; ``means (K, E, N)`` -> ``(K, E)``."""
    k, n_env = means.shape[:2]
    start = ee_now.expand(k, n_env, 3)  # (K, E, 3)
    if rest.numel():
        path = task.ee_path(promp.trajectory(means, phase=rest))  # (K, E, P', 3)
        # the way over, sampled densely: a switch must not cross the can
        bridge = start[..., None, :] + _BRIDGE.to(path)[:, None] * (path[..., :1, :] - start[..., None, :])
        path = torch.cat([bridge, path], -2)  # (K, E, 8 + P', 3)
    else:
        path = start[..., None, :]  # (K, E, 1, 3)
    return task.path_costs(path, env.expand(k, n_env, 4), start=start).sum(-1)  # (K, E)


def _apply_moves(task, envs: Tensor, q_now: Tensor, episodes: list[int], t: int, place_clearance: float,
                 generator, moved: Tensor, tries: int = 64) -> None:
    """Move the can or the target of ``episodes`` from instant ``t`` on (in place), never onto the arm."""
    idx = torch.tensor(episodes)
    n = idx.numel()
    which = torch.rand(n, generator=generator) < 0.5  # True: the can, False: the target
    cand = task.sample_envs(n * tries, generator, dtype=envs.dtype, device=envs.device).reshape(n, tries, 4)
    old = envs[idx, t][:, None].expand(-1, tries, -1)  # (n, tries, 4)
    new = torch.where(which.to(envs.device)[:, None, None], torch.cat([cand[..., :2], old[..., 2:]], -1),
                      torch.cat([old[..., :2], cand[..., 2:]], -1))  # (n, tries, 4)
    links = task.kinematics.link_positions(q_now[idx])[:, None, None]  # (n, 1, 1, F, 3)
    clear = task.skeleton_distance(links, new) > task.can_radius + place_clearance  # (n, tries)
    ok = task.valid_envs(new) & clear  # (n, tries)
    for i, e in enumerate(episodes):
        good = torch.nonzero(ok[i]).flatten()
        if good.numel():
            envs[e, t:] = new[i, int(good[0])]
            moved[e] += 1
