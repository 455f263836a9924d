"""The two rates of a policy (``planner="thread"``): a planner thread beside the control loop
that re-infers the map's means and makes the class decisions, and a tracker that answers every
tick from the newest plan, never waiting for the planner.

* :class:`Plan`: what the planner publishes, the chosen class's mean weights as a ``(Kb, D)``
  array, its label and the time ``t`` of the inputs it was made from.
* :class:`Planner`: the thread. Every ``period`` seconds it takes the newest inputs the tracker
  handed over (one tuple assigned to an attribute: the tracker takes no lock) and, when they are
  new, runs the policy's inline class choice on them (:meth:`~protorch.policy.policy.Policy.choose`:
  a decision when ``t`` entered a new ``decision_dt`` slot, the tracked class's mean otherwise)
  and publishes the plan (again one attribute).
* :class:`Tracker`: the per-tick computation in NumPy on a precomputed table of the basis at every
  whole millisecond of the motion: the plan's mean at ``t`` plus the continuity offset (the
  critically damped decay of :class:`~protorch.policy.policy.Policy`, the jump added where the
  plan changed), then the robot's limits (:class:`~protorch.policy.limits.JerkLimiter`).

The tracker calls no torch operation: torch's operators release the GIL while they run, and a
thread that gave the GIL away waits to take it back while the planner holds it (up to
``sys.getswitchinterval()``). NumPy's small ufuncs and ``@`` keep it; ``ndarray.dot`` does not
(its BLAS call lets the GIL go), so the tracker's products are ``@`` (the same bits). The
reference's tensors (``torch.from_numpy``) let it go too, briefly, once the reference is made.
While planner threads run, the
switch interval is held at :data:`SWITCH_INTERVAL` (0.5 ms; Python's default is 5 ms): the loop's
thread, woken for a tick, waits for the planner's GIL at most that long
(:class:`_SwitchInterval`).
"""

from __future__ import annotations

import atexit
import math
import sys
import threading
import time
import weakref
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .reference import Reference, as_array

__all__ = [
    "SWITCH_INTERVAL",
    "Plan",
    "Planner",
    "Tracker",
    "TwoRatePolicy",
    "basis3_np",
    "decay_np",
]


class Plan(NamedTuple):
    """A plan of the planner: ``W (Kb, D)`` the chosen class's mean weights (one column per
    joint), ``label`` its class, ``t`` the time of the inputs it was made from (s), ``motion``
    the motion it belongs to (:meth:`~protorch.policy.policy.Policy.reset` counts them)."""

    W: np.ndarray
    label: int
    t: float
    motion: int


def basis3_np(centers: np.ndarray, width: float, z: float) -> np.ndarray:
    """:func:`~protorch.policy.means.basis3` at one phase ``z`` in NumPy: ``(3, K)``."""
    d = z - centers  # (K,)
    b = np.exp(-0.5 * (d / width) ** 2)
    g = b / b.sum()
    a = -d / width**2
    s = (g * a).sum()
    g1 = g * (a - s)
    g2 = g1 * (a - s) - g * (g1 * a).sum()
    return np.stack([g, g1, g2])


def decay_np(blend: float, s: float) -> np.ndarray:
    """:func:`~protorch.policy.means.decay_matrix` with 3 rows, in NumPy: ``(3, 2)``."""
    w, e = blend, math.exp(-blend * s)
    return np.array(
        [
            [(1 + w * s) * e, s * e],
            [-w * w * s * e, (1 - w * s) * e],
            [(-w * w + w**3 * s) * e, (-2 * w + w * w * s) * e],
        ]
    )


class Tracker:
    """The reference of one motion from the plans it is given (module docstring).

    Args:
        phi_ms: ``(T_ms + 1, 3, Kb)`` the basis and its time derivatives at every whole millisecond.
        centers, width: the ProMP's basis (off the millisecond grid, :func:`basis3_np`).
        duration: seconds from phase 0 to 1 (past it the last point is held).
        blend: the offset's decay rate (1/s; ``inf``: no offset).
        limiter: a :class:`~protorch.policy.limits.JerkLimiter` or ``None``.
    """

    def __init__(
        self,
        phi_ms: np.ndarray,
        centers: np.ndarray,
        width: float,
        duration: float,
        blend: float,
        limiter=None,
    ) -> None:
        self.phi_ms, self.centers, self.width = phi_ms, centers, float(width)
        self.duration, self.blend = float(duration), float(blend)
        self.scale = np.array([1.0, 1.0 / duration, 1.0 / duration**2])[:, None]  # (3, 1)
        self.phi_end = basis3_np(centers, width, 1.0)
        self.phi_end[1:] = 0.0  # held: no velocity, no acceleration
        self.limiter = limiter
        self._at_jump = decay_np(blend, 0.0) if math.isfinite(blend) else None  # (3, 2)
        self._decays: dict = {}
        self.reset()

    def reset(self) -> None:
        """A new motion: no plan, no offset, no time."""
        self.plan: Plan | None = None
        self.t = 0.0
        self.off: np.ndarray | None = None  # (2, D)
        if self.limiter is not None:
            self.limiter.reset()

    def basis(self, t: float) -> np.ndarray:
        """``(3, Kb)`` the basis and its time derivatives at ``t`` (the table at whole
        milliseconds)."""
        if t >= self.duration:
            return self.phi_end
        i = round(t * 1000.0)
        if i < self.phi_ms.shape[0] and i * 1e-3 == t:
            return self.phi_ms[i]
        return basis3_np(self.centers, self.width, t / self.duration) * self.scale

    def _basis_near(self, t: float) -> np.ndarray:
        """:meth:`basis` with ``t`` within 1e-12 s of a whole millisecond taken as it (where a
        hand-over meets the plan: ``last_t + s`` rounds off the grid by an ulp)."""
        if t < self.duration:
            i = round(t * 1000.0)
            if i < self.phi_ms.shape[0] and abs(t - i * 1e-3) <= 1e-12:
                return self.phi_ms[i]
        return self.basis(t)

    def _decay(self, s: float) -> np.ndarray:
        hit = self._decays.get(s)
        if hit is None:
            if len(self._decays) >= 64:
                self._decays.clear()
            hit = self._decays[s] = decay_np(self.blend, s)[:2]
        return hit

    def step(self, t: float, plan: Plan, q, qd) -> np.ndarray:
        """The reference ``(3, D)`` (position, velocity, acceleration) at ``t`` (not before the
        last call's) tracking ``plan``; ``q, qd``: ``D`` measured joints each or ``None`` (the
        first call of a motion starts the reference there).

        The products are ``@``, not ``ndarray.dot`` (the same bits; ``.dot`` lets the GIL go:
        module docstring). Where the limiter hands over, the meeting with the plan is at a whole
        millisecond (``meet``: the basis there is the table's)."""
        phi = self.basis(t)  # (3, Kb)
        state = phi @ plan.W  # (3, D)
        if self._at_jump is not None:
            jump = None
            last = self.plan
            if last is not None:
                if plan is not last:  # the mean's jump where the plan changed
                    jump = phi[:2] @ (last.W - plan.W)  # (2, D)
            elif q is not None:  # start where the arm is (at rest where qd is not given)
                q = np.asarray(q, dtype=np.float64)
                jump = np.stack([q, 0.0 * q if qd is None else np.asarray(qd)]) - state[:2]
            off = self.off
            if off is not None:
                off = self._decay(t - self.t) @ off  # (2, D)
                if jump is not None:
                    off += jump
            else:
                off = jump
            if off is not None:
                self.off = off
                state += self._at_jump @ off
        last_t, changed = self.t, plan is not self.plan
        near = changed and self.plan is not None and plan.label == self.plan.label
        dt = t - last_t if self.plan is not None else 0.0
        self.plan, self.t = plan, t
        if self.limiter is not None:
            off, W = self.off, plan.W

            def future(s: float) -> np.ndarray:  # the wanted state s seconds after the last call
                at = self._basis_near(last_t + s) @ W  # (3, D)
                if off is not None:
                    at = at + (self._at_jump @ (self._decay(s - dt) @ off) if s >= dt else 0.0)
                return at

            def meet(s: float) -> float:  # the first whole millisecond s or more after last_t
                return math.ceil((last_t + s) * 1000.0 - 1e-6) * 1e-3 - last_t

            state = self.limiter.step(state, dt, future, changed, meet=meet, near=near)
        return state


SWITCH_INTERVAL = 5e-4
"""The interpreter's switch interval (s) while a planner thread runs (:class:`_SwitchInterval`)."""


class _SwitchInterval:
    """``sys.setswitchinterval`` held at :data:`SWITCH_INTERVAL` while planner threads run.

    The control loop's thread sleeps between ticks; woken, it needs the GIL, and where the
    planner holds it (its Python between torch's operators) it waits until the planner gives it
    away, at most one switch interval where the planner is on a core: up to 5 ms at Python's
    default, five ticks. 0.5 ms is longer than a tracker's call (~0.05 ms: the waiting planner
    does not push the caller off the GIL within a call) and shorter than a tick. The first
    running planner lowers the interval to it (never raises it: an application's lower setting
    stays); the last one to stop puts back the interval it found, unless the application has
    changed it since. Process-wide, as the GIL is; ``planner="process"`` shares no GIL and
    leaves it alone."""

    lock = threading.RLock()  # reentrant: a collection within may run a dropped planner's __del__
    running = 0
    saved: float | None = None  # the interval found, where it was lowered

    def __init__(self) -> None:
        cls = type(self)
        with cls.lock:
            if cls.running == 0:
                now = sys.getswitchinterval()
                cls.saved = now if now > SWITCH_INTERVAL else None
                if cls.saved is not None:
                    sys.setswitchinterval(SWITCH_INTERVAL)
            cls.running += 1
        self.held = True

    def release(self) -> None:
        """Once per planner (:meth:`Planner.close` and the thread's end both call it)."""
        cls = type(self)
        with cls.lock:
            if not self.held:
                return
            self.held = False
            cls.running -= 1
            if cls.running == 0 and cls.saved is not None:
                if math.isclose(sys.getswitchinterval(), SWITCH_INTERVAL, rel_tol=1e-3):
                    sys.setswitchinterval(cls.saved)  # not where the application set its own
                cls.saved = None


def _run(ref, period: float, stop: threading.Event, hold: _SwitchInterval) -> None:
    """The planner's loop (a weak reference to its :class:`Planner`: a planner nobody
    holds stops); the switch interval given back when it ends."""
    try:
        _loop(ref, period, stop)
    finally:
        hold.release()


def _loop(ref, period: float, stop: threading.Event) -> None:
    due = time.perf_counter()
    done = None
    while not stop.is_set():
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        due = max(due + period, time.perf_counter())
        planner = ref()
        if planner is None:
            return
        inputs = planner.inbox
        if inputs is not None and inputs is not done:
            done = inputs
            with planner.lock:
                if inputs[0] == planner.motion:  # not a motion reset() has ended since
                    plan = planner.make(*inputs)
                    planner.plan = plan
                    planner.plans += 1
        del planner


_RUNNING: weakref.WeakSet[Planner] = weakref.WeakSet()


@atexit.register
def _stop_all() -> None:
    """Stop every planner thread before the interpreter tears torch down under it."""
    for planner in list(_RUNNING):
        planner.close()
        planner._thread.join(timeout=1.0)


class Planner:
    """The planner thread (module docstring): ``make(motion, env, t, q, qd) -> Plan`` run every
    ``period`` seconds on the newest :attr:`inbox` when it is new, the result put in
    :attr:`plan`. :attr:`lock` is held while a plan is made (:meth:`new_motion` takes it).
    A daemon thread; :meth:`close` stops it (so does dropping the planner)."""

    def __init__(self, make, period: float) -> None:
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period must be a finite number of seconds > 0, got {period!r}")
        self.make, self.period = make, float(period)
        self.inbox: tuple | None = None  # (motion, env, t, q, qd): the tracker's newest inputs
        self.plan: Plan | None = None
        self.motion = 0
        self.plans = 0  # plans made
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._hold = _SwitchInterval()
        self._thread = threading.Thread(
            target=_run,
            args=(weakref.ref(self), self.period, self._stop, self._hold),
            name="protorch-planner",
            daemon=True,
        )
        self._thread.start()
        _RUNNING.add(self)

    def new_motion(self, reset) -> int:
        """Start a new motion: ``reset()`` called with the lock held (no plan is being made), the
        inputs and the plan of the old motion dropped; the new motion's number."""
        with self.lock:
            self.motion += 1
            self.inbox, self.plan = None, None
            reset()
            return self.motion

    def close(self) -> None:
        """Stop the thread (it ends within one ``period``) and give the switch interval back
        (:class:`_SwitchInterval`)."""
        self._stop.set()
        self._hold.release()

    def __del__(self) -> None:
        if hasattr(self, "_hold"):  # not where __init__ refused its arguments
            self._stop.set()
            self._hold.release()


def _values(x, n: int, name: str) -> list[float] | None:
    """``n`` values for the tracker's path: a list of Python floats of its own (``None`` stays
    ``None``), with :func:`~protorch.policy.reference.as_array`'s errors. A CPU float64 tensor or
    array (the loop's usual input) is read with ``tolist`` and checked as floats, about five
    times cheaper than ``as_array`` (no ``x.device``, no NumPy array built: the planner builds
    its own)."""
    if x is None:
        return None
    if (type(x) is Tensor and x.dtype is torch.float64 and x.is_cpu) or (
        type(x) is np.ndarray and x.dtype is _F64
    ):
        if x.shape != (n,):
            raise ValueError(f"{name} must be {(n,)} values, got shape {tuple(x.shape)}")
        vals = x.tolist()
        # a sum of finite floats is finite unless it overflows: then each value is looked at
        if not math.isfinite(sum(vals)) and not all(map(math.isfinite, vals)):
            raise ValueError(f"{name} holds NaN or inf: {vals}")
        return vals
    return as_array(x, (n,), name).tolist()


_F64 = np.dtype(np.float64)


class TwoRatePolicy:
    """``planner="thread"``'s side of :class:`~protorch.policy.policy.Policy` (a mixin): the
    input check without torch, the planner's step and the tracker's call."""

    def _check_np(self, env, t, q, qd) -> tuple:
        """:meth:`_check` without torch operations: ``env`` (``d`` values), ``t``, ``q, qd`` (``D``
        values each) or ``None``, the values as lists of Python floats of their own
        (:func:`_values`)."""
        env = _values(env, self._env_dim, "env")
        t = float(t)
        if not math.isfinite(t) or t < 0:
            raise ValueError(
                f"t must be a finite time >= 0 (seconds since the motion started), got {t!r}"
            )
        return env, t, _values(q, self._d, "q"), _values(qd, self._d, "qd")

    def _plan(self, motion: int, env, t: float, q, qd) -> Plan:
        """The planner's step: the inline class choice at the inputs the tracker handed over
        (``env``, ``q``, ``qd``: float64 arrays or lists of floats)."""
        env = np.asarray(env, dtype=np.float64)
        env_t, q_t, qd_t = (
            None if x is None else torch.as_tensor(x, dtype=torch.float64).to(self._device)
            for x in (env, q, qd)
        )
        with torch.inference_mode():
            c, w = self.choose(env_t, t, q_t, env.tolist(), self.basis_at(t), qd_t)  # w (1, N)
            self._m.t = t
            W = w.view(self._d, self._kb).T.cpu().numpy().copy()  # (Kb, D)
        return Plan(W, self._label_list[c], t, motion)

    def _track(self, env, t, q, qd) -> Reference:
        """:meth:`reference` with ``planner="thread"``: the inputs handed to the planner, the newest
        plan tracked (made here only where the motion has none yet: its first call without
        ``reset(env)``)."""
        env, t, q, qd = self._check_np(env, t, q, qd)
        tr, planner, motion = self._tracker, self._planner, self._motion
        t = max(t, tr.t)
        planner.inbox = (motion, env, t, q, qd)
        plan = planner.plan
        if plan is None or plan.motion != motion:
            plan = tr.plan
            if plan is None:
                with planner.lock:
                    plan = planner.plan = self._plan(motion, env, t, q, qd)
        state = tr.step(t, plan, q, qd)  # (3, D)
        return Reference(
            torch.from_numpy(state[0]),
            torch.from_numpy(state[1]),
            torch.from_numpy(state[2]),
            plan.label,
            plan.t,
        )
