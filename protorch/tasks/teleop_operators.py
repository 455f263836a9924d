"""Simulated people at the controls of the beam (:class:`~protorch.tasks.TeleopWindowTask`), as
plug-ins.

**The protocol** (:class:`Operator`): any class with

* ``__init__(self, seed: int)``,
* ``reset(self, start, end, wall) -> None``: poses ``(7,)`` (xyz, quaternion wxyz) of the start and
  end and the wall's pose ``(4,)`` (x, y, z, yaw) as the trial begins,
* ``act(self, t, pose, wall) -> Tensor``: the pose ``(7,)`` the hand moves toward at time ``t``
  (s), given the beam's actual pose ``(7,)`` and the wall's pose ``(4,)`` as it is at ``t`` (the
  operator decides what it perceives of it).

:func:`load_operator` resolves ``PATH.py:CLASS`` or a dotted ``module.CLASS`` and refuses a class
without the protocol; :func:`probe_operator` calls one on a trial's start and refuses a pose that
is not 7 finite numbers with a rotation, both with one line naming the class.

**The shipped operators** plan a path from the start, through two points ``offset`` before and
after where they *believe* the window is, to the end (a Catmull-Rom curve with a minimum-jerk
progress, :func:`plan_poses`), rolling the beam upright on the way in (one of the two classes)
and back on the way out, re-planned at every call from the wall they perceive (``lag`` seconds
old). :class:`ScreenOperator` is the paper's person at a 2-D screen (Sec. IV-A, the errors of
:class:`~protorch.tasks.SimulatedOperator`: depth misjudged, the beam tilted, tremor);
:class:`VariedOperator` draws its traits from its seed (pace, depth and tilt errors, lag, which way
it rolls the beam), so ``VariedOperator(0..n-1)`` is a population.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import sys
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import torch
from torch import Tensor

from ..primitives.pose import align_quaternions, quaternion_slerp
from ..primitives.quaternions import axis_angle_to_quaternion, quaternion_raw_multiply
from .curves import catmull_rom, smooth_noise
from .teleop_window import TeleopWindowTask

__all__ = [
    "Operator",
    "ScreenOperator",
    "VariedOperator",
    "load_operator",
    "probe_operator",
    "plan_poses",
    "careful_demonstrations",
    "OPERATORS",
]

_DEG = math.pi / 180


@runtime_checkable
class Operator(Protocol):
    """What a simulated operator provides (module docstring)."""

    def __init__(self, seed: int) -> None: ...

    def reset(self, start: Tensor, end: Tensor, wall: Tensor) -> None: ...

    def act(self, t: float, pose: Tensor, wall: Tensor) -> Tensor: ...


def _smooth(x: Tensor) -> Tensor:
    x = x.clamp(0, 1)
    return x**3 * (10 - 15 * x + 6 * x**2)


def plan_poses(
    task,
    s: Tensor,
    wall: Tensor,
    start: Tensor,
    end: Tensor,
    *,
    cls: int,
    depth: float = 0.0,
    lateral=(0.0, 0.0),
    tilt: float = 0.0,
    other=(0.0, 0.0),
    offset: float = 0.1,
    turn_start: float = 0.15,
    turn_back: float = 0.8,
) -> Tensor:
    """The planned poses ``(P, 7)`` at progresses ``s (P,)`` in ``[0, 1]`` through the window of
    ``wall (4,)`` as believed: ``depth`` (m) further along the normal, ``lateral (2,)`` (m) off in
    the window's plane, the upright pose of class ``cls`` rolled ``tilt`` (rad) further about the
    normal and ``other (2,)`` about the two other axes. The beam starts rolling up at
    ``turn_start`` of the way to the front point and is upright there; it rolls back from the back
    point and is at the end orientation ``turn_back`` of the way from there to the end."""
    s = s.to(wall.dtype).reshape(-1)
    c, rot = task.wall_frame(wall)
    a = rot[:, 0]
    lat = torch.as_tensor(lateral, dtype=wall.dtype)
    cb = c + depth * a + rot[:, 1:] @ lat
    via = torch.stack([start[:3], cb - offset * a, cb + offset * a, end[:3]])[None]  # (1, 4, 3)
    path = catmull_rom(via, s[None])[0]  # (P, 3)
    err = quaternion_raw_multiply(
        axis_angle_to_quaternion(rot[:, 1:] @ torch.as_tensor(other, dtype=wall.dtype)),
        axis_angle_to_quaternion(tilt * a),
    )
    q_pass = quaternion_raw_multiply(err, task.passing_quaternions(wall)[cls])  # (4,)
    chord = (via[0, 1:] - via[0, :-1]).norm(dim=-1)
    knots = chord.cumsum(-1) / chord.sum()
    k1, k2 = knots[0], knots[1]
    b0, b1 = turn_start * k1, k2 + turn_back * (1 - k2)
    up, down = _smooth((s - b0) / (k1 - b0)), _smooth((s - k2) / (b1 - k2))
    q_in = quaternion_slerp(start[3:], q_pass, up)  # (P, 4)
    q_out = quaternion_slerp(q_pass, end[3:], down)
    q = torch.where(
        (s <= k1)[:, None], q_in, torch.where((s <= k2)[:, None], q_pass.expand_as(q_in), q_out)
    )
    return torch.cat([path, q], -1)


class _Planner:
    """The shared behaviour of the shipped operators: traits set in ``__init__`` by a subclass,
    errors drawn per trial in :meth:`reset`, the plan re-made at every :meth:`act`."""

    duration = (3.0, 5.0)  # s, the trial's pace (drawn per trial)
    lag = 0.2  # s, the wall perceived this late
    depth_bias, depth_std = 0.05, 0.2  # m, along the normal
    lateral_std = 0.015  # m, in the window's plane
    tilt_std, other_std = 30.0, 5.0  # deg, about the normal and the other two axes
    jitter_std, jitter_angle_std = 0.004, 1.5  # m, deg
    cls_p = 0.5  # probability of rolling the beam up the first way (class 0)
    _err: dict[str, Any]  # this trial's errors, drawn by reset()

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self._gen = torch.Generator().manual_seed(self.seed)
        self._task: TeleopWindowTask | None = None
        self._plan: tuple[Tensor, Tensor] | None = None  # (wall seen, (G, 7) poses)

    def bind(self, task) -> None:
        """The task whose geometry the plan uses (the experiment binds it; default geometry
        otherwise)."""
        self._task = task

    def _draw(self, *shape) -> Tensor:
        return torch.randn(shape, generator=self._gen, dtype=torch.float64)

    def _uniform(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=self._gen, dtype=torch.float64))

    def reset(self, start: Tensor, end: Tensor, wall: Tensor) -> None:
        if self._task is None:
            self._task = TeleopWindowTask()
        self._start, self._end = start.double(), end.double()
        self._T = self._uniform(*self.duration)
        self._skew = self._uniform(0.8, 1.25)
        self._cls = int(float(torch.rand((), generator=self._gen)) >= self.cls_p)
        self._err = dict(
            depth=self.depth_bias + self.depth_std * float(self._draw()),
            lateral=tuple((self.lateral_std * self._draw(2)).tolist()),
            tilt=self.tilt_std * _DEG * float(self._draw()),
            other=tuple((self.other_std * _DEG * self._draw(2)).tolist()),
            offset=self._uniform(0.05, 0.15),
            turn_start=self._uniform(0.01, 0.3),
            turn_back=self._uniform(0.6, 1.0),
        )
        self._grid = torch.linspace(0, 1, 401, dtype=torch.float64)  # (G,) progress
        self._env = torch.sin(math.pi * self._grid)[:, None]  # (G, 1) tremor vanishing at the ends
        self._jit = smooth_noise(self._grid[None], self.jitter_std, self._gen, dim=3, knots=24)[
            0
        ]  # (G, 3)
        self._wob = smooth_noise(
            self._grid[None], self.jitter_angle_std * _DEG, self._gen, dim=3, knots=24
        )[0]
        self._plan = None
        self._seen = [(0.0, wall.double().clone())]

    def perceived(self, t: float, wall: Tensor) -> Tensor:
        """The wall as this operator sees it at ``t``: its pose ``lag`` seconds ago."""
        self._seen.append((float(t), wall.double().clone()))
        old = [w for tt, w in self._seen if tt <= t - self.lag]
        self._seen = [(tt, w) for tt, w in self._seen if tt > t - self.lag - 1.0]
        return old[-1] if old else self._seen[0][1]

    def progress(self, t: float) -> float:
        """The planned progress in ``[0, 1]`` at ``t``: a minimum-jerk profile over the trial's
        duration."""
        u = min(max(t / self._T, 0.0), 1.0) ** self._skew
        return u**3 * (10 - 15 * u + 6 * u**2)

    def act(self, t: float, pose: Tensor, wall: Tensor) -> Tensor:
        s = self.progress(float(t))
        seen = self.perceived(t, wall)
        if self._plan is None or not torch.equal(
            seen, self._plan[0]
        ):  # re-planned when the wall moved
            grid = plan_poses(
                self._task, self._grid, seen, self._start, self._end, cls=self._cls, **self._err
            )
            q = quaternion_raw_multiply(
                axis_angle_to_quaternion(self._wob * self._env), grid[:, 3:]
            )
            q = align_quaternions(q, self._start[3:])  # sign-continuous along the grid
            self._plan = (seen, torch.cat([grid[:, :3] + self._jit * self._env, q], -1))  # (G, 7)
        x = s * (len(self._grid) - 1)
        i = min(int(x), len(self._grid) - 2)
        f = x - i
        p = (1 - f) * self._plan[1][i] + f * self._plan[1][
            i + 1
        ]  # the plan between two grid points
        return torch.cat([p[:3], p[3:] / p[3:].norm()])


class ScreenOperator(_Planner):
    """The paper's person moving the beam while watching a 2-D screen along the wall normal
    (:class:`~protorch.tasks.SimulatedOperator`'s errors: the depth misjudged by ``N(0.05, 0.2)``
    m, the upright pose tilted ``N(0, 30)`` deg about the normal, tremor), perceiving the wall
    0.2 s late, taking 3-5 s, rolling the beam up either way with equal odds."""


class VariedOperator(_Planner):
    """One of a population: its traits drawn from ``seed`` (pace 2.5-6 s, perception lag 0.1-0.4 s,
    depth error std 0.05-0.25 m, tilt std 10-35 deg, lateral error 0.01-0.03 m, tremor x0.5-2,
    and a preferred roll: 85 % of its trials one way, that way drawn from the seed)."""

    def __init__(self, seed: int) -> None:
        super().__init__(seed)
        g = torch.Generator().manual_seed(10_000 + self.seed)
        r = torch.rand(8, generator=g, dtype=torch.float64).tolist()
        lo = 2.5 + 2.0 * r[0]
        self.duration = (lo, lo + 1.5 * r[1] + 0.2)
        self.lag = 0.1 + 0.3 * r[2]
        self.depth_std = 0.05 + 0.2 * r[3]
        self.tilt_std = 10.0 + 25.0 * r[4]
        self.lateral_std = 0.01 + 0.02 * r[5]
        self.jitter_std = 0.004 * (0.5 + 1.5 * r[6])
        self.cls_p = 0.85 if r[7] < 0.5 else 0.15


OPERATORS = {"screen": ScreenOperator, "varied": VariedOperator}


def load_operator(spec: str) -> type:
    """The operator class ``spec`` names: ``screen`` / ``varied`` (shipped), ``PATH.py:CLASS``
    (a file anywhere) or ``module.CLASS`` / ``module:CLASS`` (importable). Raises ``ValueError``
    with one line naming what is wrong (no such file, module or class; no :class:`Operator`
    protocol)."""
    spec = str(spec)
    if spec in OPERATORS:
        return OPERATORS[spec]
    if ":" in spec:
        where, _, name = spec.rpartition(":")
    else:
        where, _, name = spec.rpartition(".")
    if not where or not name:
        raise ValueError(
            f"teleop.operator={spec!r}: give {'/'.join(OPERATORS)}, PATH.py:CLASS or module.CLASS"
        )
    if where.endswith(".py"):
        path = Path(where).expanduser()
        if not path.is_file():
            raise ValueError(f"teleop.operator={spec!r}: no file {path}")
        mod_name = f"_protorch_operator_{abs(hash(str(path.resolve())))}"
        loader_spec = importlib.util.spec_from_file_location(mod_name, path)
        if loader_spec is None or loader_spec.loader is None:
            raise ValueError(f"teleop.operator={spec!r}: cannot load {path} as a module")
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[mod_name] = module
        try:
            loader_spec.loader.exec_module(module)
        except Exception as exc:
            raise ValueError(
                f"teleop.operator={spec!r}: importing {path} raised {type(exc).__name__}: {exc}"
            ) from None
    else:
        try:
            module = importlib.import_module(where)
        except ImportError as exc:
            raise ValueError(f"teleop.operator={spec!r}: cannot import {where} ({exc})") from None
    cls = getattr(module, name, None)
    if not isinstance(cls, type):
        raise ValueError(f"teleop.operator={spec!r}: {where} has no class {name}")
    missing = [m for m in ("reset", "act") if not callable(getattr(cls, m, None))]
    if missing:
        raise ValueError(
            f"teleop.operator={spec!r}: class {name} lacks {', '.join(missing)} (an operator needs "
            "__init__(seed), reset(start, end, wall), act(t, pose, wall))"
        )
    return cls


def probe_operator(
    cls: type,
    task,
    start: Tensor,
    end: Tensor,
    wall: Tensor,
    *,
    seed: int = 0,
    times=(0.0, 0.5, 1.5),
) -> None:
    """Build ``cls(seed)``, reset it and call ``act`` at a few times of a static trial; raise
    ``ValueError`` (one line naming the class) where it raises or returns anything but 7 finite
    numbers with a non-zero quaternion."""
    name = f"{cls.__module__}.{cls.__qualname__}"
    try:
        op = cls(seed)
        if hasattr(op, "bind"):
            op.bind(task)
        op.reset(start.clone(), end.clone(), wall.clone())
        for t in times:
            check_pose(op.act(float(t), start.clone(), wall.clone()), name, t)
    except ValueError:
        raise
    except Exception as exc:
        raise ValueError(f"operator {name} raised {type(exc).__name__}: {exc}") from None


def check_pose(pose, name: str, t: float) -> Tensor:
    """``pose`` as a float64 ``(7,)`` tensor; ``ValueError`` naming the operator otherwise."""
    p = torch.as_tensor(pose)
    if p.shape != (7,):
        raise ValueError(
            f"operator {name}.act returned shape {tuple(p.shape)} at t={t:g} s; it must return "
            "a pose (7,): xyz, quaternion wxyz"
        )
    p = p.to(torch.float64)
    if not bool(torch.isfinite(p).all()):
        raise ValueError(
            f"operator {name}.act returned a non-finite pose {p.tolist()} at t={t:g} s"
        )
    if float(p[3:].norm()) < 1e-8:
        raise ValueError(f"operator {name}.act returned a zero quaternion at t={t:g} s")
    return p


def careful_demonstrations(
    task, num_envs: int, per_env: int, generator: torch.Generator, *, num_steps: int = 100
) -> tuple[list, Tensor]:
    """Demonstrations by a careful person at a static wall: the plan without errors (offsets and
    turning points varied), tremor of 3 mm and 1 deg; classes alternate between walls."""
    envs = task.sample_envs(num_envs, generator)
    start, end = task.endpoint_poses()
    s = torch.linspace(0, 1, num_steps, dtype=torch.float64)
    s = s**3 * (10 - 15 * s + 6 * s**2)
    demos, env_rows = [], []
    for i, env in enumerate(envs):
        for _ in range(per_env):
            r = torch.rand(3, generator=generator, dtype=torch.float64).tolist()
            p = plan_poses(
                task,
                s,
                env,
                start,
                end,
                cls=i % 2,
                offset=0.08 + 0.08 * r[0],
                turn_start=0.05 + 0.3 * r[1],
                turn_back=0.6 + 0.35 * r[2],
            )
            jit = (
                smooth_noise(s[None], 0.003, generator, dim=3, knots=12)[0]
                * torch.sin(math.pi * s)[:, None]
            )
            wob = (
                smooth_noise(s[None], 1.0 * _DEG, generator, dim=3, knots=12)[0]
                * torch.sin(math.pi * s)[:, None]
            )
            q = quaternion_raw_multiply(axis_angle_to_quaternion(wob), p[:, 3:])
            demos.append(torch.cat([p[:, :3] + jit, align_quaternions(q, start[3:])], -1))
            env_rows.append(env)
    return demos, torch.stack(env_rows)
