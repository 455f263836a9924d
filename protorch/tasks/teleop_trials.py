"""Teleoperation trials with a moving wall: the wall's schedule and the closed-loop simulation.

**The wall's schedule** (:class:`WallSchedule`, drawn by :func:`draw_schedules` from a seed): the
wall starts at a pose drawn in the middle ``start_fraction`` of the task's range and makes
``moves`` moves, each starting at a time uniform in ``move_window`` (s): a slide along its own
width of ``slide`` m (times ``U(0.5, 1)``, either sign) and along its normal of half that, and a
turn about the vertical of ``turn`` deg (the same), at ``slide_speed`` m/s and ``turn_speed``
deg/s (the slower of the two sets the move's duration; a minimum-jerk profile). The pose is
clipped to the task's range (where the map was trained).

**A trial** (:func:`run_trials`, ``B`` trials in lockstep at a control period ``dt``): at each step
the operator says where the hand goes (``act(t, pose, wall(t))``), the guide (none, fixed at the
first wall pose, or adaptive) turns that wish into the device's pose, and the beam is checked
against the wall at that instant (and halfway from the last pose). A trial succeeds when the beam
reaches the end pose within the task's tolerances before ``time_limit`` without ever touching the
wall; its time is when it got there (``time_limit`` otherwise); its effort is
``int |p_w - p_x| + (L / 2) angle(q_w, q_x) dt`` (m s: the rotation as the beam tip's
displacement), the disagreement between the operator's wish and the executed motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..primitives.pose import quaternion_distance
from .teleop_operators import check_pose

__all__ = ["WallSchedule", "draw_schedules", "run_trials", "CONDITIONS", "SCHEDULE_DEFAULTS"]

CONDITIONS = ("none", "fixed", "adaptive")
SCHEDULE_DEFAULTS = dict(
    moves=2,
    slide=0.1,
    turn=15.0,
    slide_speed=0.15,
    turn_speed=20.0,
    move_window=(0.3, 2.0),
    start_fraction=0.6,
)


@dataclass
class WallSchedule:
    """``B`` walls: first poses ``env0 (B, 4)``, move starts ``t0 (B, M)`` and durations ``dur (B,
    M)``
    (s), displacements ``delta (B, M, 4)``; ``low``/``high`` ``(4,)`` the range the pose is
    clipped to."""

    env0: Tensor
    t0: Tensor
    dur: Tensor
    delta: Tensor
    low: Tensor
    high: Tensor

    def at(self, t: float) -> Tensor:
        """The walls' poses ``(B, 4)`` at time ``t`` (s)."""
        u = ((t - self.t0) / self.dur).clamp(0, 1)  # (B, M)
        s = u**3 * (10 - 15 * u + 6 * u**2)
        env = self.env0 + (s[..., None] * self.delta).sum(1)
        return torch.maximum(torch.minimum(env, self.high), self.low)

    def rows(self) -> list[dict]:
        """One plain dict per wall (for the study CSV and the metrics)."""
        return [
            {
                "env0": self.env0[i].tolist(),
                "t0": self.t0[i].tolist(),
                "dur": self.dur[i].tolist(),
                "delta": self.delta[i].tolist(),
            }
            for i in range(self.env0.shape[0])
        ]


def draw_schedules(task, n: int, seed: int, **settings) -> WallSchedule:
    """``n`` wall schedules from ``seed`` (module docstring; ``settings``:
    :data:`SCHEDULE_DEFAULTS` keys)."""
    unknown = sorted(set(settings) - set(SCHEDULE_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown wall setting(s) {unknown}; allowed: {sorted(SCHEDULE_DEFAULTS)}")
    c = {**SCHEDULE_DEFAULTS, **settings}
    m = int(c["moves"])
    for key in ("slide", "turn", "slide_speed", "turn_speed", "start_fraction"):
        if not (math.isfinite(float(c[key])) and float(c[key]) >= 0):
            raise ValueError(f"wall.{key} must be finite and >= 0, got {c[key]}")
    if (
        m < 0
        or float(c["slide_speed"]) <= 0
        or float(c["turn_speed"]) <= 0
        or not 0 <= c["start_fraction"] <= 1
    ):
        raise ValueError("wall.moves must be >= 0, the speeds > 0 and start_fraction in [0, 1]")
    g = torch.Generator().manual_seed(int(seed))
    f64 = torch.float64
    low, high = torch.tensor(task.env_low, dtype=f64), torch.tensor(task.env_high, dtype=f64)
    mid, half = 0.5 * (low + high), 0.5 * (high - low) * float(c["start_fraction"])
    env0 = mid + half * (2 * torch.rand(n, 4, generator=g, dtype=f64) - 1)

    def amount(scale: float, *shape) -> Tensor:
        sign = torch.where(torch.rand(*shape, generator=g) < 0.5, -1.0, 1.0).to(f64)
        return sign * scale * (0.5 + 0.5 * torch.rand(*shape, generator=g, dtype=f64))

    lat, dep, turn = (
        amount(c["slide"], n, m),
        amount(0.5 * c["slide"], n, m),
        amount(math.radians(c["turn"]), n, m),
    )
    yaw = env0[:, 3:4]
    delta = torch.stack(
        [
            dep * torch.cos(yaw) - lat * torch.sin(yaw),
            dep * torch.sin(yaw) + lat * torch.cos(yaw),
            torch.zeros_like(lat),
            turn,
        ],
        -1,
    )  # (n, m, 4)
    lo, hi = c["move_window"]
    t0 = lo + (hi - lo) * torch.rand(n, m, generator=g, dtype=f64)
    dur = torch.maximum(
        (lat**2 + dep**2).sqrt() / c["slide_speed"], turn.abs() / math.radians(c["turn_speed"])
    )
    return WallSchedule(env0=env0, t0=t0, dur=dur.clamp_min(1e-3), delta=delta, low=low, high=high)


def run_trials(
    task,
    operators: list,
    walls: WallSchedule,
    condition: str,
    guide=None,
    *,
    dt: float = 0.02,
    time_limit: float = 10.0,
    record: bool = False,
) -> dict:
    """Simulate ``B = len(operators)`` trials (each operator already built; ``walls`` holds ``B``
    schedules) in one condition (module docstring). Returns per trial ``success``, ``collided``,
    ``time``, ``effort``, ``freedom`` (mean position compliance of the guide, 1 without one) and,
    with ``record``, ``poses (B, S, 7)``, ``wishes (B, S, 7)``, ``walls (B, S, 4)``."""
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; choose from {', '.join(CONDITIONS)}")
    if condition != "none" and guide is None:
        raise ValueError(f"condition {condition!r} needs a guide")
    b = len(operators)
    start, end = task.endpoint_poses()
    names = [f"{type(o).__module__}.{type(o).__qualname__}" for o in operators]
    env_first = walls.at(0.0)
    for i, op in enumerate(operators):
        op.reset(start.clone(), end.clone(), env_first[i].clone())
    steps = int(round(time_limit / dt))
    x = start.expand(b, 7).clone()
    state = guide.start(b) if guide is not None else None
    done = torch.zeros(b, dtype=torch.bool)
    hit = torch.zeros(b, dtype=torch.bool)
    time = torch.full((b,), float(time_limit), dtype=torch.float64)
    effort = torch.zeros(b, dtype=torch.float64)
    comp_sum, comp_n = torch.zeros(b, dtype=torch.float64), torch.zeros(b, dtype=torch.float64)
    rec: dict = {"poses": [], "wishes": [], "walls": []}
    half = 0.5 * task.beam_length
    for s in range(1, steps + 1):
        t = s * dt
        env = walls.at(t)  # (B, 4)
        wish = torch.stack(
            [
                check_pose(op.act(t, x[i].clone(), env[i].clone()), names[i], t)
                for i, op in enumerate(operators)
            ]
        )  # (B, 7)
        if condition == "none":
            new, comp = wish, torch.ones(b, dtype=torch.float64)
        else:
            cond_env = env if condition == "adaptive" else env_first
            new, state, comp = guide.step(state, wish, cond_env, dt)
        active = ~done
        mid = x + 0.5 * (new - x)
        mid = torch.cat(
            [mid[:, :3], mid[:, 3:] / mid[:, 3:].norm(dim=-1, keepdim=True).clamp_min(1e-9)], -1
        )
        touch = task.collides_at(new, env) | task.collides_at(mid, env)
        hit |= touch & active
        gap = (wish[:, :3] - new[:, :3]).norm(dim=-1) + half * quaternion_distance(
            wish[:, 3:], new[:, 3:]
        )
        effort += torch.where(active, gap * dt, torch.zeros_like(gap))
        comp_sum += torch.where(active, comp, torch.zeros_like(comp))
        comp_n += active.double()
        x = torch.where(active[:, None], new, x)
        arrived = active & task.at_pose(x, end)
        time = torch.where(arrived, torch.full_like(time, t), time)
        done |= arrived
        if record:
            rec["poses"].append(x.clone())
            rec["wishes"].append(wish)
            rec["walls"].append(env)
        if bool(done.all()):
            break
    out = {
        "success": done & ~hit,
        "collided": hit,
        "arrived": done,
        "time": time,
        "effort": effort,
        "freedom": comp_sum / comp_n.clamp_min(1),
    }
    if record:
        out.update({k: torch.stack(v, 1) for k, v in rec.items()})
    return out
