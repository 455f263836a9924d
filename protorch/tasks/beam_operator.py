"""The simulated person of the beam-window task (:class:`~protorch.tasks.BeamWindowTask`, the
paper's Sec. IV-A): a beam moved with a haptic device while watching a 2-D screen, misjudging the
window's depth and the beam's orientation (:class:`SimulatedOperator`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor

from ..primitives.pose import align_quaternions, quaternion_slerp
from ..primitives.quaternions import axis_angle_to_quaternion, quaternion_raw_multiply
from .curves import catmull_rom, smooth_noise

__all__ = ["SimulatedOperator"]


class WindowGeometry(Protocol):
    """What the operator reads of :class:`~protorch.tasks.BeamWindowTask` (which imports this
    module): the window's pose and the poses through it."""

    wall_position: tuple

    def via_poses(self) -> tuple[Tensor, Tensor, Tensor, Tensor]: ...

    def wall_rotation(self) -> Tensor: ...

    def approach_direction(self) -> Tensor: ...

    def passing_quaternion(self) -> Tensor: ...


@dataclass
class SimulatedOperator:
    """A person moving the beam with a haptic device while watching a 2-D screen.

    The camera looks along the wall normal, so the window's position in the wall plane is seen
    well but its depth is not. Each trial the operator plans a path from the start, through two
    points ``plan_offset`` before and after where they *believe* the window is, to the end
    (a Catmull-Rom curve with a minimum-jerk speed profile, like the point-particle demonstrator),
    turning the beam upright on the way in and back on the way out. The errors:

    * **depth misjudged**: the believed window is ``N(depth_bias, depth_std)`` off along the
      normal, so the beam is turned too late (still turning when it reaches the wall) or turned
      back too early;
    * **orientation off**: the upright pose is rotated by ``N(0, tilt_std)`` about the wall normal
      (the beam's extent across the narrow window is ``L sin(tilt)``) and by ``N(0,
      orientation_std)`` about the other two axes;
    * **position off** in the window plane (``lateral_std``) and at the start and end
      (``endpoint_std``, ``endpoint_angle_std``);
    * **jitter**: hand tremor, a smooth random wiggle of ``jitter_std`` (m) and ``jitter_angle_std``
      on ``jitter_knots`` knots per trial, vanishing at the two ends.

    The beam starts turning upright at a fraction ``U(turn_start)`` of the way to the front point
    and is upright there; it starts turning back at the back point and reaches the end orientation
    at a fraction ``U(turn_back)`` of the way from there to the end (a minimum-jerk profile of the
    progress along the path). Angles are in degrees here (``*_std``); ``lengths`` is the range of
    samples per trial. With the defaults and the default task, about 79 % of the trials fail
    (measured over 1000: 34 % with the depth error alone, 63 % with the tilt alone, none with
    jitter and the lateral error alone); the paper's person failed 10 of 10.
    """

    depth_bias: float = 0.05
    depth_std: float = 0.2
    lateral_std: float = 0.015
    tilt_std: float = 30.0
    orientation_std: float = 5.0
    plan_offset: tuple = (0.05, 0.15)
    turn_start: tuple = (0.01, 0.3)
    turn_back: tuple = (0.6, 1.0)
    endpoint_std: float = 0.01
    endpoint_angle_std: float = 2.0
    jitter_std: float = 0.004
    jitter_angle_std: float = 1.5
    jitter_knots: int = 24
    lengths: tuple = (300, 500)

    def __post_init__(self) -> None:
        for key in (
            "depth_std",
            "lateral_std",
            "tilt_std",
            "orientation_std",
            "endpoint_std",
            "endpoint_angle_std",
            "jitter_std",
            "jitter_angle_std",
        ):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(
                    f"operator {key} must be finite and >= 0, got {getattr(self, key)}"
                )
            setattr(self, key, v)
        if not math.isfinite(float(self.depth_bias)):
            raise ValueError(f"operator depth_bias must be finite, got {self.depth_bias}")
        self.depth_bias = float(self.depth_bias)
        for key, lo_ok in (("plan_offset", 0.0), ("turn_start", 0.0), ("turn_back", 0.0)):
            lo, hi = (float(v) for v in getattr(self, key))
            if not (lo_ok < lo <= hi) or (key != "plan_offset" and hi > 1):
                bound = "" if key == "plan_offset" else " <= 1"
                raise ValueError(
                    f"operator {key} must be (lo, hi) with 0 < lo <= hi{bound}, got "
                    f"{getattr(self, key)}"
                )
            setattr(self, key, (lo, hi))
        t_min, t_max = (int(v) for v in self.lengths)
        if not 4 <= t_min <= t_max:
            raise ValueError(
                f"operator lengths must be (lo, hi) with 4 <= lo <= hi, got {self.lengths}"
            )
        self.lengths = (t_min, t_max)
        if int(self.jitter_knots) < 2:
            raise ValueError(f"operator jitter_knots must be >= 2, got {self.jitter_knots}")

    def intentions(
        self,
        task: WindowGeometry,
        num: int,
        generator: torch.Generator | None = None,
        *,
        dtype: torch.dtype = torch.float64,
    ) -> tuple[Tensor, Tensor]:
        """``num`` planned trials through ``task``'s window (a
        :class:`~protorch.tasks.BeamWindowTask`),
        padded: poses ``(num, T_max, 7)`` (a trial repeats its last pose after its length) and
        ``lengths (num,)``. Unassisted, the device follows them exactly."""
        if isinstance(num, bool) or int(num) != num or int(num) < 1:
            raise ValueError(f"num must be an int >= 1, got {num}")
        n, g, f64 = int(num), generator, torch.float64
        deg = math.pi / 180

        def randn(*shape):
            return torch.randn(*shape, generator=g, dtype=f64)

        def uniform(lo_hi, *shape):
            lo, hi = lo_hi
            return lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=f64)

        start, _, _, end = task.via_poses()
        rot = task.wall_rotation()  # (3, 3)
        a = task.approach_direction()  # (3,)
        c = torch.tensor(task.wall_position, dtype=f64)
        # where the operator believes the window is
        depth = self.depth_bias + self.depth_std * randn(n, 1)  # (n, 1)
        lateral = self.lateral_std * randn(n, 2)  # (n, 2)
        c_b = c + depth * a + lateral @ rot[:, 1:].T  # (n, 3)
        off = uniform(self.plan_offset, n, 1)  # (n, 1)
        p_start = start[:3] + self.endpoint_std * randn(n, 3)
        p_end = end[:3] + self.endpoint_std * randn(n, 3)
        via = torch.stack([p_start, c_b - off * a, c_b + off * a, p_end], 1)  # (n, 4, 3)
        # the upright pose they aim for: tilted about the wall normal and a little about the rest
        tilt = self.tilt_std * deg * randn(n, 1) * rot[:, 0]  # (n, 3) rotation vector
        other = self.orientation_std * deg * randn(n, 2) @ rot[:, 1:].T  # (n, 3)
        err = quaternion_raw_multiply(
            axis_angle_to_quaternion(other), axis_angle_to_quaternion(tilt)
        )
        q_pass = quaternion_raw_multiply(err, task.passing_quaternion().expand(n, 4))  # (n, 4)
        q_start = quaternion_raw_multiply(
            axis_angle_to_quaternion(self.endpoint_angle_std * deg * randn(n, 3)),
            start[3:].expand(n, 4),
        )
        q_end = quaternion_raw_multiply(
            axis_angle_to_quaternion(self.endpoint_angle_std * deg * randn(n, 3)),
            end[3:].expand(n, 4),
        )
        # timing: a minimum-jerk progress along the curve with a random skew
        t_min, t_max = self.lengths
        length = torch.randint(t_min, t_max + 1, (n, 1), generator=g)  # (n, 1)
        skew = 0.8 + 0.45 * torch.rand(n, 1, generator=g, dtype=f64)
        u = (torch.arange(t_max, dtype=f64) / (length - 1)).clamp(max=1)  # (n, T_max)
        v = u**skew
        s = v**3 * (10 - 15 * v + 6 * v**2)  # (n, T_max) progress in [0, 1]
        path = catmull_rom(via, s)  # (n, T_max, 3)
        # orientation keyed to the progress: turn up before the front point, back after the back
        # point
        chord = (via[:, 1:] - via[:, :-1]).norm(dim=-1)  # (n, 3)
        knots = chord.cumsum(-1) / chord.sum(-1, keepdim=True)  # (n, 3): front, back, end
        k1, k2 = knots[:, :1], knots[:, 1:2]  # (n, 1)
        b0 = uniform(self.turn_start, n, 1) * k1  # turning up starts here
        b1 = k2 + uniform(self.turn_back, n, 1) * (1 - k2)  # turning back ends here

        def smooth(x):
            x = x.clamp(0, 1)
            return x**3 * (10 - 15 * x + 6 * x**2)

        up = smooth((s - b0) / (k1 - b0))  # (n, T_max)
        down = smooth((s - k2) / (b1 - k2))
        q_in = quaternion_slerp(q_start[:, None], q_pass[:, None], up)  # (n, T_max, 4)
        q_out = quaternion_slerp(q_pass[:, None], q_end[:, None], down)
        q = torch.where(
            (s <= k1)[..., None],
            q_in,
            torch.where((s <= k2)[..., None], q_pass[:, None].expand_as(q_in), q_out),
        )  # (n, T_max, 4)
        # jitter, vanishing at the ends
        env = torch.sin(torch.pi * s)[..., None]  # (n, T_max, 1)
        path = path + smooth_noise(u, self.jitter_std, g, dim=3, knots=self.jitter_knots) * env
        wobble = (
            smooth_noise(u, self.jitter_angle_std * deg, g, dim=3, knots=self.jitter_knots) * env
        )
        q = quaternion_raw_multiply(axis_angle_to_quaternion(wobble), q)
        q = align_quaternions(q / q.norm(dim=-1, keepdim=True), start[3:])
        return torch.cat([path, q], -1).to(dtype), length[:, 0]

    def trials(
        self,
        task: WindowGeometry,
        num: int,
        generator: torch.Generator | None = None,
        *,
        dtype: torch.dtype = torch.float64,
    ) -> list[Tensor]:
        """``num`` unassisted trials ``(T_i, 7)`` of random lengths (the demonstrations)."""
        poses, lengths = self.intentions(task, num, generator, dtype=dtype)
        return [p[:t].clone() for p, t in zip(poses, lengths.tolist())]
