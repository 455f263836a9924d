"""The online test of the paper's Fig. 7: the arm reaches while a person moves the can or the
target, and it switches between passing the can on the left and on the right on the fly.

At every control step the environment map is queried once for all ``E`` episodes and every
label (homotopy class) at their current environments; each class's predicted mean is scored by
the task's objectives on *the rest of the motion from where the arm is now* (the end effector
now, then the class's mean end-effector path from the current phase to the end:
:meth:`~protorch.tasks.ArmReachTask.path_costs` with the current position as start, summed), and
the arm keeps its class unless another one scores lower by more than ``switch_margin``
(hysteresis: two nearly equal classes, a can right on the straight line, would otherwise chatter).
The class choice and the velocity command are :mod:`protorch.control.arm_choice`'s, shared with
the physics test (:mod:`protorch.control.physics`). This is the label-aware inference of the
self-improvement loop
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
the arm (under the task's collision model: its skeleton or its link volumes,
:mod:`protorch.tasks.arm.collision`) at least ``place_clearance`` from the moved can's surface.
The person moves things at once (a jump), which is the hardest case for the controller.

Success over the whole episode, at every instant with the environment of that instant: the arm
more than ``margin`` from the can's surface and above the table (under the task's collision
model), every joint inside its limits, and, after the hold, the end effector within ``goal_tol`` of
the final
target. The arm starts at rest at the task's start configuration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from ..checks import check_number, check_tensor
from ..tasks.arm.collision import above_table
from .arm_choice import (
    ArmClassChoice,
    Follow,
    draw_moves,
    rest_scores,
    velocity_command_acceleration,
)
from .episodes import (
    Timing,
    check_timing,
    check_velocity_loop_stable,
    episode_walk,
    hold_last,
    track,
)

__all__ = [
    "ArmEpisodeResult",
    "arm_follow",
    "arm_outcome",
    "count_switches",
    "rest_scores",
    "run_arm_episodes",
]


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
    min_can_gap: (
        Tensor  # (E,) the arm (task's collision model) to the can's surface, over the episode
    )
    moves: Tensor  # (E,) long, moves that happened
    map_queries: (
        int  # (environment, class) answers the map computed; unchanged environments reuse theirs
    )
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
            "success_rate_with_switch": float(self.success[switched].double().mean())
            if bool(switched.any())
            else float("nan"),
            "moves": int(self.moves.sum()),
            "map_queries": self.map_queries,
            "collision_rate": float(self.collided.double().mean()),
            "limit_violation_rate": float((~self.within_limits).double().mean()),
            "final_goal_distance_median": float(d.median()),
            "goal_reached_rate": float((d <= self.task.goal_tol).double().mean())
            if self.task is not None
            else float("nan"),
        }

    def episode(self, i: int) -> dict:
        """Numpy arrays of episode ``i`` for :mod:`protorch.figures.arm`: ``links (T+1, F, 3)`` the
        arm's
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

        return {
            "links": np_(links),
            "ee": np_(links[:, -1]),
            "means": np_(means),
            "envs": np_(self.envs[i]),
            "labels": np_(self.labels[i]),
            "dt": self.dt,
            "success": bool(self.success[i]),
        }


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
    max_acceleration: Sequence[float] | None = None,
    moves: Sequence[int] = (1, 2),
    move_window: tuple[float, float] = (0.1, 0.6),
    place_clearance: float = 0.05,
    switch_margin: float = 0.02,
    check: bool = True,
    switch_clearance: float = 0.01,
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
        max_acceleration: per joint (rad/s^2); ``None``: the task's robot's
            (:attr:`~protorch.robots.Robot.max_acceleration`). The velocity limits are the robot's.
        moves, move_window, place_clearance: how many moves an episode gets (one value drawn
            uniformly from ``moves``), in which phase range, and how far from the arm a moved
            can stays (beyond its radius).
        switch_margin: hysteresis of the class choice, in units of the summed objectives.
        check: pass over a class whose plan for the rest of the motion, from the arm's joints
            now, touches the can (the task's collision model and ``margin``) while another
            class's is clear (:func:`~protorch.control.arm_choice.rest_blocked`); ``False``: the
            summed objectives alone choose.
        switch_clearance: the check's hysteresis (m): a class other than the tracked one counts as
            clear only with ``margin + switch_clearance`` to spare
            (:func:`~protorch.control.arm_choice.checked_choice`).
        reuse_answers: the map is asked every control step, but an environment that did not
            change since the last step gets its last answer again (the map is a pure function
            of it) instead of a new GP solve; ``False`` solves every step (same result, slower).
        record: keep the tracked mean weights of every instant (for figures).
    """
    env_map, promp = getattr(model, "env_map", None), getattr(model, "promp", None)
    if env_map is None or not callable(getattr(env_map, "predict_mean", None)) or promp is None:
        raise ValueError(
            "model must have .env_map (a protorch EnvMap) and .promp, e.g. protorch.load(run_dir)"
        )
    if promp.num_dof != task.num_dof:
        raise ValueError(f"the ProMP has {promp.num_dof} DoF but the arm has {task.num_dof} joints")
    timing = check_timing(dt, duration, hold)
    kp = check_number(kp, "kp")
    check_velocity_loop_stable(kp, timing.dt)
    place_clearance = check_number(place_clearance, "place_clearance", allow_zero=True)
    switch_margin = check_number(switch_margin, "switch_margin", allow_zero=True)
    switch_clearance = check_number(switch_clearance, "switch_clearance", allow_zero=True)
    moves = [int(m) for m in moves]
    if not moves or min(moves) < 0:
        raise ValueError(f"moves must be a non-empty list of ints >= 0, got {moves}")
    lo_w, hi_w = (float(v) for v in move_window)
    if not 0 <= lo_w <= hi_w <= 1:
        raise ValueError(f"move_window must be (lo, hi) with 0 <= lo <= hi <= 1, got {move_window}")
    kw = {"dtype": promp.basis.dtype, "device": promp.basis.device}
    walk = episode_walk(env0, walk, timing, 4)
    if walk is not None:
        envs = hold_last(task.check_envs(walk, "walk").to(**kw), timing.held)  # (E, T+1, 4)
        schedule = [[] for _ in range(walk.shape[0])]
    else:
        env0 = task.check_envs(check_tensor(env0, "env0", ndim=2), "env0").to(**kw)
        if env0.shape[0] < 1:
            raise ValueError(f"env0 holds no environment: shape {tuple(env0.shape)}")
        envs = env0[:, None].repeat(1, timing.total + 1, 1)  # (E, T+1, 4), rewritten by the moves
        schedule = draw_moves(env0.shape[0], timing.moving, moves, (lo_w, hi_w), generator)
    if max_acceleration is None:
        max_acceleration = task.robot.max_acceleration
    choice = ArmClassChoice(
        task,
        env_map,
        promp,
        envs,
        schedule,
        timing.total,
        place_clearance=place_clearance,
        switch_margin=switch_margin,
        generator=generator,
        reuse_answers=reuse_answers,
        check=bool(check),
        follow=arm_follow(task, kp, max_acceleration, timing, **kw),
        switch_clearance=switch_clearance,
    )
    arm = _KinematicArm(choice, task, timing, kp=kp, max_acceleration=max_acceleration)
    run = track(
        arm, promp, timing, envs.shape[0], task.start_config(**kw), record=record, markers=False
    )
    q = run.positions  # (E, T+1, J)
    return ArmEpisodeResult(
        q=q,
        qd=run.velocities,
        envs=envs,
        labels=choice.labels,
        weights=run.weights,
        **arm_outcome(task, q, envs),
        moves=choice.moved,
        map_queries=choice.queries,
        dt=timing.dt,
        duration=timing.duration,
        hold=timing.hold,
        num_moving_steps=timing.moving,
        promp=promp,
        task=task,
    )


def arm_outcome(task, q: Tensor, envs: Tensor) -> dict[str, Tensor]:
    """The moving test's verdict on joint paths ``q (E, T+1, J)`` in the environments ``envs (E,
    T+1, 4)`` (module docstring): ``success``, ``collided``, ``within_limits``,
    ``final_goal_distance``, ``min_can_distance``, ``min_can_gap``, each ``(E,)``."""
    with torch.no_grad():
        kin = task.kinematics
        frames = kin.frames(q)  # (E, T+1, F, 4, 4)
        min_dist = task.skeleton_distance(frames[:, :, None, :, :3, 3], envs).amin(-1)  # (E,)
        gap = task.frames_gap(frames[:, :, None], envs).amin(-1)  # (E,)
        collided = gap <= task.margin
        limits = kin.within_limits(q).all(-1)
        goal = (frames[:, -1, -1, :3, 3] - task.goal_point(envs[:, -1])).norm(dim=-1)
        success = ~collided & limits & above_table(task, frames) & (goal <= task.goal_tol)
    return {
        "success": success,
        "collided": collided,
        "within_limits": limits,
        "final_goal_distance": goal,
        "min_can_distance": min_dist,
        "min_can_gap": gap,
    }


def arm_follow(
    task,
    kp: float,
    max_acceleration,
    timing: Timing,
    dtype=torch.float64,
    device=None,
    tables: dict | None = None,
) -> Follow:
    """The moving tests' velocity command for the plan check's rollout
    (:class:`~protorch.control.arm_choice.Follow`): gain ``kp``, the robot's velocity limits,
    ``max_acceleration`` (per joint or one number; ``None``: the robot's), the control step and the
    motion's duration (``timing``); ``tables``: the rollout's basis values kept between plans (a
    policy's, :attr:`Follow.tables`)."""
    kw = {"dtype": dtype, "device": device}
    amax = task.robot.max_acceleration if max_acceleration is None else max_acceleration
    return Follow(
        float(kp),
        task.kinematics.max_velocity.to(**kw),
        torch.as_tensor(amax, **kw).expand(task.num_dof),
        timing.dt,
        timing.duration,
        tables,
    )


class _KinematicArm:
    """The arm for :func:`~protorch.control.episodes.track`: the class choice
    (:class:`~protorch.control.arm_choice.ArmClassChoice`) answers, the arm moves by the velocity
    command within the joint velocity and acceleration limits."""

    def __init__(
        self, choice: ArmClassChoice, task, timing: Timing, *, kp: float, max_acceleration
    ) -> None:
        kw = {"dtype": choice.envs.dtype, "device": choice.envs.device}
        self.choice, self.dt, self.kp = choice, timing.dt, kp
        self.vmax = task.kinematics.max_velocity.to(**kw)  # (J,)
        self.amax = torch.as_tensor(max_acceleration, **kw).expand(task.num_dof)  # (J,)

    def answer(self, t: int, z: float, q: Tensor, qd: Tensor | None = None) -> Tensor:
        return self.choice.answer(t, z, q, qd)

    def acceleration(self, q: Tensor, qd: Tensor, m: Tensor, m_vel: Tensor) -> Tensor:
        return velocity_command_acceleration(
            q, qd, m, m_vel, kp=self.kp, vmax=self.vmax, amax=self.amax, dt=self.dt
        )
