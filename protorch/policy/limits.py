"""The robot's joint limits at every tick of a reference: velocity, acceleration and jerk
(:class:`JerkLimiter`, Ruckig's online trajectory generation for the hand-over).

A policy's reference is the chosen class's mean plus a continuity offset. Where the plan changes
(a class switch, an environment jump, the first call) the offset keeps position and velocity
continuous, but its acceleration steps, and a step of acceleration is an unbounded jerk; a mean
that ends its motion steps its velocity to 0. :class:`JerkLimiter` passes the wanted state
through while the step from the last output is within the limits, and otherwise follows it with
Ruckig (time-optimal, jerk-limited trajectories between two kinematic states, Berscheid and
Kroeger 2021): from the last output to the wanted state, sampled one interval later, until the
wanted state is reached within one interval; from there on the wanted state is passed through
again. The meeting time is the first at which Ruckig reaches the wanted state, of the times the
caller allows (the tracker: whole milliseconds, where the wanted state is a table lookup). A
hand-over under way that a new plan of the same class interrupts keeps its meeting time where
Ruckig's shortest time to the new plan's state then is within a tick of it (a new plan moves the
meeting little, and the search from the next tick, growing 20% a step, met later each time:
re-planned again and again); otherwise it is searched from the next tick. Keeping the old
meeting whenever it could be met stretched Ruckig's profile where the new plan could be met
sooner, and in the example loop the arm swung into the can.

The limits hold between consecutive outputs: ``|qd| <= max_velocity``, ``|qdd| <=
max_acceleration``, ``|qdd_t - qdd_{t-dt}| <= max_jerk dt`` and the finite differences
``|q_t - q_{t-dt}| <= max_velocity dt``, ``|qd_t - qd_{t-dt}| <= max_acceleration dt`` per joint
(to Ruckig's own tolerance, about 1e-9 relative), provided the wanted state's velocity and
acceleration are within the limits where it is passed through (where they are not, Ruckig
follows it with its target clipped to the limits).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "LIMITS",
    "JerkLimiter",
    "JointwiseLimiter",
    "make_limiter",
    "robot_limits",
    "within_limits",
]

LIMITS = ("auto", True, False, "joint", "together")  # the values of a policy's ``limits``

DEFAULT_JERK = (
    7500.0  # rad/s^3 per joint where a robot states none (Franka's, of the same order as KUKA's)
)


def robot_limits(
    robot, dof: int, *, max_velocity=None, max_acceleration=None, max_jerk=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(max_velocity, max_acceleration, max_jerk)``, each ``(dof,)`` float64: the arguments
    where given (a number or one per joint), else the robot's ``max_velocity``,
    ``max_acceleration``, ``max_jerk`` (``robot.max_jerk``, the Panda's Franka's published 7,500;
    a robot without one: :data:`DEFAULT_JERK`).
    Raises ``ValueError`` for a limit that is missing, of the wrong size or not > 0."""
    out = []
    for name, given in (
        ("max_velocity", max_velocity),
        ("max_acceleration", max_acceleration),
        ("max_jerk", max_jerk),
    ):
        v = given if given is not None else getattr(robot, name, None)
        if name == "max_jerk" and v is not None and np.size(v) == 0:
            v = None  # a robot description made without one
        if v is None and name == "max_jerk":
            v = DEFAULT_JERK
        if v is None:
            raise ValueError(f"{name}: the robot states none; pass {name}=")
        a = (
            np.broadcast_to(np.asarray(v, dtype=np.float64), (dof,)).copy()
            if np.ndim(v) == 0
            else np.asarray(v, dtype=np.float64)
        )
        if a.shape != (dof,) or not (np.isfinite(a).all() and (a > 0).all()):
            raise ValueError(
                f"{name} must be a number or {dof} numbers, each finite and > 0, got {v!r}"
            )
        out.append(a)
    return out[0], out[1], out[2]


def make_limiter(
    limits,
    planner: str,
    robot,
    dof: int,
    *,
    max_velocity=None,
    max_acceleration=None,
    max_jerk=None,
):
    """The limiter of a policy's reference (:class:`~protorch.policy.policy.Policy`'s
    ``limits``), or ``None``: ``"auto"`` (the default) is :class:`JointwiseLimiter` for
    ``planner="thread"`` or ``"process"`` where the robot states its velocity and acceleration
    limits (or they are given) and none for ``planner="inline"`` (the moving test's reference,
    unlimited) or a task without a robot; ``True`` or ``"joint"``, :class:`JointwiseLimiter`;
    ``"together"``, :class:`JerkLimiter`; ``False``, none. The limits: :func:`robot_limits`.
    Raises ``ValueError`` for another ``limits``, a limiter asked of the inline planner, or a limit
    that is missing or not > 0."""
    if not (limits is True or limits is False or (isinstance(limits, str) and limits in LIMITS)):
        raise ValueError(
            f"limits must be 'auto', true, false, 'joint' or 'together', got {limits!r}"
        )
    if limits == "auto":
        stated = all(
            given is not None or getattr(robot, name, None) is not None
            for name, given in (
                ("max_velocity", max_velocity),
                ("max_acceleration", max_acceleration),
            )
        )
        limits = "joint" if planner != "inline" and stated else False
    if limits is False:
        return None
    if planner == "inline":
        raise ValueError(
            f"limits={limits!r} needs planner='thread' or 'process' (the inline reference is the "
            "moving test's, unlimited)"
        )
    lim = robot_limits(
        robot,
        dof,
        max_velocity=max_velocity,
        max_acceleration=max_acceleration,
        max_jerk=max_jerk,
    )
    return (JerkLimiter if limits == "together" else JointwiseLimiter)(*lim)


def within_limits(
    tests: dict, vmax: np.ndarray, amax: np.ndarray, jmax: np.ndarray, last, want, dt: float
) -> np.ndarray:
    """Per joint ``(D,)`` bool, whether ``want (3, D)`` follows ``last (3, D)`` within the limits
    ``(D,)``: velocity and
    acceleration within theirs, the acceleration's change within ``max_jerk dt``, the position's
    and the velocity's within ``max_velocity dt`` and ``max_acceleration dt`` (the finite
    differences at the tick within the limits: at a coarse tick the next two allow more), and
    position and velocity where a constant jerk over ``dt`` takes them (within what ``max_jerk``
    moves them over ``dt``), all seven linear in ``(last, want)``: one product with a matrix kept
    in ``tests`` per ``dt``; and the velocity ``want`` reaches once its acceleration is brought to
    0 at ``max_jerk`` (``v + a |a| / (2 max_jerk)``) within ``max_velocity``: a state nearer the
    velocity limit, still accelerating toward it, is left for a hand-over (no jerk-limited motion
    from it keeps the velocity limit)."""
    hit = tests.get(dt)
    if hit is None:
        if len(tests) >= 64:
            tests.clear()
        h = dt * dt
        M = np.array(
            [
                [0, 0, -1, 0, 0, 1],  # the change of acceleration
                [0, 0, 0, 0, 1, 0],  # the velocity
                [0, 0, 0, 0, 0, 1],  # the acceleration
                [0, -1, -dt / 2, 0, 1, -dt / 2],  # velocity off a constant jerk's
                [-1, -dt, -h / 3, 1, 0, -h / 6],  # position off it
                [-1, 0, 0, 1, 0, 0],  # the change of position
                [0, -1, 0, 0, 1, 0],  # the change of velocity
            ],
            dtype=np.float64,
        )
        j, v, a = jmax, vmax, amax
        bound = np.stack([j * dt, v, a, j * h / 2, j * h * dt / 6, v * dt, a * dt])  # (7, D)
        hit = tests[dt] = (M, bound)
    M, bound = hit
    ok = (np.abs(M @ np.concatenate([last, want])) <= bound).all(0)  # (D,)
    # and where the acceleration, brought to 0 at the largest jerk, leaves the velocity: a state
    # at the velocity limit still accelerating toward it cannot be followed within it
    a = want[2]
    return ok & (np.abs(want[1] + a * np.abs(a) / (2.0 * jmax)) <= vmax)


class JerkLimiter:
    """A wanted state ``(3, D)`` (position, velocity, acceleration) per tick -> the state sent
    ``(3, D)``, within the limits (module docstring). ``max_velocity``, ``max_acceleration``,
    ``max_jerk``: ``(D,)``. :meth:`reset` before a new motion; :attr:`following` counts the ticks
    Ruckig computed, :attr:`failed` those where Ruckig found no trajectory (the wanted state is
    then sent, clipped to the velocity and acceleration limits)."""

    def __init__(self, max_velocity, max_acceleration, max_jerk) -> None:
        from ruckig import InputParameter, Result, Ruckig, RuckigError, Trajectory

        self._error, self._ok = RuckigError, (Result.Working, Result.Finished)

        self.vmax = np.asarray(max_velocity, dtype=np.float64)  # (D,)
        self.amax = np.asarray(max_acceleration, dtype=np.float64)  # (D,)
        self.jmax = np.asarray(max_jerk, dtype=np.float64)  # (D,)
        d = self.vmax.shape[0]
        if self.amax.shape != (d,) or self.jmax.shape != (d,):
            raise ValueError(
                f"the limits must have one value per joint: {self.vmax.shape}, {self.amax.shape}, "
                f"{self.jmax.shape}"
            )
        self._otg, self._inp, self._traj = Ruckig(d), InputParameter(d), Trajectory(d)
        self._vlist, self._alist = self.vmax.tolist(), self.amax.tolist()
        self._jlist = self.jmax.tolist()
        self._inp.max_velocity = self.vmax.tolist()
        self._inp.max_acceleration = self.amax.tolist()
        self._inp.max_jerk = self.jmax.tolist()
        self.following = self.failed = 0
        self._tests: dict = {}  # dt -> the step's tests (_within)
        self.reset()

    def reset(self) -> None:
        """A new motion: the next state is taken as it is wanted (its acceleration clipped)."""
        self.last: np.ndarray | None = None  # (3, D) the last state sent
        self._join: float | None = None  # the duration of the hand-over trajectory followed now
        self._elapsed = 0.0  # seconds into it

    def step(
        self,
        want: np.ndarray,
        dt: float,
        future,
        changed: bool = False,
        *,
        meet=None,
        within: bool | None = None,
        near: bool = False,
    ) -> np.ndarray:
        """The state to send ``dt`` seconds after the last one (``want (3, D)``; a new array).
        ``future(s)``: the wanted state ``s`` seconds after the last one, ``(3, D)``, where a
        hand-over meets it; ``changed``: the wanted motion is a new one (a hand-over under way
        is planned afresh); ``meet(s)``: the first time ``>= s`` at which a hand-over may meet
        the wanted motion (``None``: any; the tracker's: its whole milliseconds, where
        ``future`` is a table lookup); ``within``: the step's limit test where the caller has
        made it (:func:`within_limits`); ``near``: the new motion is near the old one (the
        tracker: a new plan of the same class), so a hand-over under way is re-planned from its
        old meeting time on."""
        last = self.last
        if last is None:
            out = self._clipped(want)
            self.last, self._join = out, None
            return out.copy()
        if dt <= 0.0:
            return last.copy()
        guess = dt
        if self._join is not None and changed:  # re-planned (near: from its old meeting on)
            if near:
                guess = max(self._join - self._elapsed, dt)
            self._join = None
        if self._join is not None:  # on a hand-over trajectory: follow it to its end
            self._elapsed += dt
            if self._elapsed < self._join - 1e-12:
                self.last = out = np.array(self._traj.at_time(self._elapsed))  # (3, D)
                return out.copy()
            self._join = None
        if within is None:
            within = self._within(last, want, dt)
        if within:
            self.last = out = want.copy()
            return out.copy()
        self.last = out = self._start(last, want, dt, future, meet, guess)
        return out.copy()

    def _within(self, last: np.ndarray, want: np.ndarray, dt: float) -> bool:
        """:func:`within_limits` of this limiter's joints."""
        return bool(
            within_limits(self._tests, self.vmax, self.amax, self.jmax, last, want, dt).all()
        )

    def _start(
        self, last: np.ndarray, want: np.ndarray, dt: float, future, meet, guess: float
    ) -> np.ndarray:
        """A hand-over trajectory from ``last`` to the wanted motion (``future``), meeting it at
        the first time it can (every joint at once, Ruckig's time synchronisation; of the times
        ``meet`` allows), its state ``dt`` in. ``guess``: ``dt``, or where a hand-over under way
        is planned afresh, the time the old one would have met its motion: kept where Ruckig's
        shortest time to the new motion's state then is within a tick of it (a new plan moves
        the meeting little), else searched from the next tick (a meeting later than the first
        possible one stretches Ruckig's profile, which may swing the joint away and back)."""
        self.following += 1
        inp = self._inp
        inp.current_position, inp.current_velocity, inp.current_acceleration = last.tolist()
        ahead, res = dt, None
        if guess > dt:  # the old meeting, where the new motion is met then and not a tick sooner
            g = meet(guess) if meet is not None else guess
            inp.minimum_duration = None
            res = self._toward(future(g))
            if res is not None and g - dt < self._traj.duration <= g:
                ahead = g
        if ahead == dt:  # (a rejected guess's result is replaced here)
            # the first meeting time T at which the wanted state at T can be reached by T
            # (``want`` is the wanted state one tick on)
            for _ in range(16):
                inp.minimum_duration = None
                res = self._toward(want if ahead == dt else future(ahead))
                if res is None or self._traj.duration <= ahead:
                    break
                ahead = max(self._traj.duration, 1.2 * ahead)
                if meet is not None:
                    ahead = meet(ahead)
        if res is not None:  # meet it exactly then (every joint at once)
            inp.minimum_duration = ahead
            res = self._toward(want if ahead == dt else future(ahead))
        if res not in self._ok:
            self.failed += 1
            return self._clipped(want)
        self._join, self._elapsed = self._traj.duration, dt
        if dt >= self._join:
            self._join = None
            return np.array(self._traj.at_time(self._traj.duration))
        return np.array(self._traj.at_time(dt))  # (3, D)

    def _toward(self, target: np.ndarray):
        """Ruckig's trajectory from the input's current state to ``target (3, D)`` (its velocity
        and acceleration clipped to the limits; where its acceleration cannot be held at its
        velocity, acceleration 0): the result, or ``None``."""
        inp = self._inp
        p, v, a = target.tolist()  # floats: clipped in Python (np.clip's dispatch costs ~2 us)
        inp.target_position = p
        v = [min(max(x, -m), m) for x, m in zip(v, self._vlist)]
        inp.target_velocity = v
        inp.target_acceleration = [
            self._braking(min(max(x, -m), m), y, vm, jm)
            for x, y, m, vm, jm in zip(a, v, self._alist, self._vlist, self._jlist)
        ]
        res = self._calculate()
        if res is None:
            inp.target_acceleration = [0.0] * len(self.amax)
            res = self._calculate()
        return res

    def _clipped(self, want: np.ndarray) -> np.ndarray:
        """A copy of ``want (3, D)`` with its velocity and acceleration clipped to the limits and
        its acceleration held to what the velocity limit allows (:meth:`_braking`, every
        joint): what is sent where no hand-over is planned."""
        out = want.copy()
        np.clip(out[1], -self.vmax, self.vmax, out=out[1])
        np.clip(out[2], -self.amax, self.amax, out=out[2])
        cap = np.sqrt(np.maximum(2.0 * self.jmax * (self.vmax - np.abs(out[1])), 0.0))  # (D,)
        out[2] = np.where(out[2] * out[1] > 0.0, np.clip(out[2], -cap, cap), out[2])
        return out

    @staticmethod
    def _braking(a: float, v: float, vmax: float, jmax: float) -> float:
        """``a`` held to what the velocity limit allows at ``v``: where ``a`` drives ``v`` toward
        the limit, ``|a| <= sqrt(2 max_jerk (max_velocity - |v|))`` (brought to 0 at the largest
        jerk, the velocity then stops at the limit: :func:`within_limits`)."""
        if a * v > 0.0:
            cap = math.sqrt(max(2.0 * jmax * (vmax - abs(v)), 0.0))
            return min(a, cap) if a > 0.0 else max(a, -cap)
        return a

    def _calculate(self):
        try:
            return self._otg.calculate(self._inp, self._traj)
        except self._error:  # a target state that leaves the limits whatever is done
            return None


class JointwiseLimiter:
    """:class:`JerkLimiter` joint by joint: one 1-joint limiter per joint, each with its own
    hand-over and its own meeting time (a fast joint is not slowed to the slowest joint's
    hand-over, as Ruckig's time synchronisation of all joints does). The same limits hold per
    joint; the joints are not synchronised during a hand-over. ``step`` as
    :class:`JerkLimiter`'s; :attr:`following`, :attr:`failed` summed over the joints."""

    def __init__(self, max_velocity, max_acceleration, max_jerk) -> None:
        v, a, j = (
            np.asarray(x, dtype=np.float64) for x in (max_velocity, max_acceleration, max_jerk)
        )
        if not (v.shape == a.shape == j.shape and v.ndim == 1):
            raise ValueError(
                f"the limits must have one value per joint: {v.shape}, {a.shape}, {j.shape}"
            )
        self.vmax, self.amax, self.jmax = v, a, j  # (D,)
        self.joints = [JerkLimiter(v[i : i + 1], a[i : i + 1], j[i : i + 1]) for i in range(len(v))]
        self._tests: dict = {}  # dt -> the step's tests, all joints at once (within_limits)
        self.reset()

    @property
    def following(self) -> int:
        return sum(x.following for x in self.joints)

    @property
    def failed(self) -> int:
        return sum(x.failed for x in self.joints)

    def reset(self) -> None:
        for x in self.joints:
            x.reset()
        self._last: np.ndarray | None = None  # (3, D) the last state sent, every joint
        self._following = False  # a joint on a hand-over

    def step(
        self,
        want: np.ndarray,
        dt: float,
        future,
        changed: bool = False,
        *,
        meet=None,
        near: bool = False,
    ) -> np.ndarray:
        """:meth:`JerkLimiter.step` per joint: ``want (3, D)`` -> ``(3, D)``. Where no joint is on
        a hand-over (or ``changed`` ends them) and every joint's step is within the limits, the
        wanted state is passed through in one test of all joints (what each joint's limiter
        would do, without a Python call per joint)."""
        last = self._last
        ok = None
        if last is not None and dt > 0.0:
            ok = within_limits(self._tests, self.vmax, self.amax, self.jmax, last, want, dt)
        if ok is not None and (changed or not self._following) and ok.all():
            if self._following:  # changed: the hand-overs under way end, as each joint's would
                for lim in self.joints:
                    lim._join = None
                self._following = False
            self._last = want.copy()
            return want.copy()
        out = want.copy()  # (3, D): the joints passed through keep the wanted state
        memo: dict = {}

        def at(s: float) -> np.ndarray:  # the wanted state s ahead, computed once per s
            hit = memo.get(s)
            if hit is None:
                hit = memo[s] = future(s)  # (3, D)
            return hit

        following = False
        for i, lim in enumerate(self.joints):
            if ok is not None and ok[i] and (changed or lim._join is None):
                lim._join = None  # within its limits, no hand-over left: passed through
                continue
            if lim._join is None and last is not None:  # passed through since its last step
                lim.last = last[:, i : i + 1].copy()
            out[:, i : i + 1] = lim.step(
                want[:, i : i + 1],
                dt,
                lambda s, i=i: at(s)[:, i : i + 1],
                changed,
                meet=meet,
                within=None if ok is None else bool(ok[i]),
                near=near,
            )
            following = following or lim._join is not None
        self._last = out.copy()
        self._following = following
        return out
