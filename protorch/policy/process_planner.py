"""``planner="process"``: the planner of :mod:`~protorch.policy.two_rate` in a child process
(forked, so the policy is the parent's), the inputs and the plans passed through shared memory:
the caller's thread never shares a GIL with the planner.

Two shared float64 arrays, each written by one side only under a sequence lock (the writer makes
the count odd, writes, makes it even; the reader copies and takes the copy where the count was
even and unchanged across it): the **inbox** ``[seq, motion, t, has q, has qd, env (d), q (D), qd
(D)]`` (the tracker's newest inputs) and the **plan** ``[seq, motion, label, t, plans, W (Kb D)]``
(the child's newest plan). The child wakes every ``period`` seconds, plans on the inbox when it
is new (a new motion number resets its class choice first) and publishes; a third array holds
the stop flag.
"""

from __future__ import annotations

import atexit
import math
import multiprocessing as mp
import threading
import time
import weakref

import numpy as np

from .two_rate import Plan

__all__ = ["ProcessPlanner"]

_HEAD_IN, _HEAD_PLAN = 5, 5  # the header lengths of the two arrays


def _read(arr: np.ndarray) -> np.ndarray | None:
    """A consistent copy of a sequence-locked array, or ``None`` (being written)."""
    s0 = arr[0]
    if s0 % 2:
        return None
    out = arr.copy()
    return out if arr[0] == s0 and out[0] == s0 else None


def _write(arr: np.ndarray, values: np.ndarray) -> None:
    """Write ``values`` into ``arr[1:]`` under the sequence lock."""
    arr[0] += 1  # odd: being written
    arr[1:] = values
    arr[0] += 1


def _child(policy, inbox, plan, ctl, period: float, d: int, nd: int) -> None:
    """The child's loop (module docstring)."""
    import torch

    torch.set_num_threads(1)
    inbox, plan, ctl = (np.frombuffer(a.get_obj()) for a in (inbox, plan, ctl))
    motion, seen, made = -1.0, -1.0, 0
    due = time.perf_counter()
    while ctl[0] == 0.0:
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        due = max(due + period, time.perf_counter())
        box = _read(inbox)
        if box is None or box[0] == seen or box[0] == 0.0:
            continue
        seen = box[0]
        if box[1] != motion:
            motion = box[1]
            policy._reset_choice()
        env = box[_HEAD_IN : _HEAD_IN + d]
        q = box[_HEAD_IN + d : _HEAD_IN + d + nd] if box[3] else None
        qd = box[_HEAD_IN + d + nd :] if box[4] else None
        p = policy._plan(int(motion), env, float(box[2]), q, qd)
        made += 1
        _write(plan, np.concatenate([[p.motion, p.label, p.t, made], p.W.ravel()]))


_RUNNING: weakref.WeakSet[ProcessPlanner] = weakref.WeakSet()


@atexit.register
def _stop_all() -> None:
    for planner in list(_RUNNING):
        planner.close()


class ProcessPlanner:
    """:class:`~protorch.policy.two_rate.Planner`'s interface (``inbox``, ``plan``, ``lock``,
    ``plans``, :meth:`new_motion`, :meth:`close`) with the planner in a forked child (module
    docstring). ``policy._plan`` runs in the child on its copy of the policy."""

    def __init__(self, policy, period: float) -> None:
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period must be a finite number of seconds > 0, got {period!r}")
        self.period = float(period)
        d, nd, kb = policy._env_dim, policy._d, policy._kb
        self._dims = (d, nd, kb)
        ctx = mp.get_context("fork")
        self._in = ctx.Array("d", _HEAD_IN + d + 2 * nd)
        self._out = ctx.Array("d", _HEAD_PLAN + kb * nd)
        self._ctl = ctx.Array("d", 1)
        self._inbox = np.frombuffer(self._in.get_obj())  # type: ignore[call-overload]
        self._shared = np.frombuffer(self._out.get_obj())  # type: ignore[call-overload]
        self._stop = np.frombuffer(self._ctl.get_obj())  # type: ignore[call-overload]
        self._seen = 0.0  # the plan array's count last read
        self._plan: Plan | None = None
        self.motion = 0
        self.lock = threading.Lock()
        self._proc = ctx.Process(
            target=_child,
            args=(policy, self._in, self._out, self._ctl, self.period, d, nd),
            name="protorch-planner",
            daemon=True,
        )
        self._proc.start()
        _RUNNING.add(self)

    @property
    def plans(self) -> int:
        """Plans the child made."""
        return int(self._shared[4])

    @property
    def inbox(self) -> None:
        return None

    @inbox.setter
    def inbox(self, inputs: tuple) -> None:
        """``(motion, env, t, q, qd)``: the tracker's newest inputs, into shared memory."""
        motion, env, t, q, qd = inputs
        d, nd, _ = self._dims
        box = self._inbox
        box[0] += 1
        box[1:5] = (motion, t, q is not None, qd is not None)
        box[_HEAD_IN : _HEAD_IN + d] = env
        if q is not None:
            box[_HEAD_IN + d : _HEAD_IN + d + nd] = q
        if qd is not None:
            box[_HEAD_IN + d + nd :] = qd
        box[0] += 1

    @property
    def plan(self) -> Plan | None:
        """The newest plan: the child's where it published one since the last read."""
        s = self._shared[0]
        if s != self._seen and s % 2 == 0:
            got = _read(self._shared)
            if got is not None:
                self._seen = got[0]
                _, nd, kb = self._dims
                W = got[_HEAD_PLAN:].reshape(kb, nd)  # (Kb, D)
                self._plan = Plan(W, int(got[2]), float(got[3]), int(got[1]))
        return self._plan

    @plan.setter
    def plan(self, plan: Plan | None) -> None:
        self._plan = plan

    def new_motion(self, reset) -> int:
        """A new motion: the child resets its class choice at the first inputs of it."""
        with self.lock:
            self.motion += 1
            self._plan = None
            self._seen = self._shared[0]
            return self.motion

    def wait_plan(self, motion: int, timeout: float = 10.0) -> Plan:
        """The child's first plan of ``motion`` (its inputs handed over already)."""
        end = time.perf_counter() + timeout
        while time.perf_counter() < end:
            plan = self.plan
            if plan is not None and plan.motion == motion:
                return plan
            if not self._proc.is_alive():
                raise RuntimeError("the planner process has ended")
            time.sleep(min(self.period, 1e-3))
        raise TimeoutError(f"the planner process made no plan within {timeout} s")

    def close(self) -> None:
        """Stop the child (it ends within one ``period``)."""
        self._stop[0] = 1.0
        if self._proc.is_alive():
            self._proc.join(timeout=max(1.0, 4 * self.period))
        if self._proc.is_alive():
            self._proc.kill()

    def __del__(self) -> None:
        try:
            self._stop[0] = 1.0
        except Exception:
            pass
