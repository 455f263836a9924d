"""The two rates (protorch.policy.two_rate): the tracker on plans made at every call is the inline
reference, it never waits for a slow planner, the planner thread keeps up with a loop and ends
with its policy; the jerk limiter keeps velocity, acceleration and jerk within the limits and
gives the wanted state back once it can."""

from __future__ import annotations

import gc
import math
import sys
import time

import numpy as np
import pytest
import torch

from protorch.policy.limits import JerkLimiter, robot_limits
from protorch.policy.two_rate import (
    SWITCH_INTERVAL,
    Plan,
    Tracker,
    _SwitchInterval,
    _values,
    basis3_np,
    decay_np,
)
from protorch.robots.published import FRANKA_JOINT_LIMITS
from tests.control.test_policy import toy_policy

F64 = torch.float64


def walk(n: int, seed: int = 0) -> torch.Tensor:
    """``(n, 2)`` environments of the toy map: a drift with jumps every 97 calls."""
    g = torch.Generator().manual_seed(seed)
    base = torch.tensor([0.3, 0.3], dtype=F64) + torch.linspace(0, 0.4, n, dtype=F64)[:, None]
    jumps = torch.zeros(n, 2, dtype=F64)
    jumps[::97] = 0.2 * torch.rand(len(range(0, n, 97)), 2, generator=g, dtype=F64)
    return base + jumps.cumsum(0) % 0.3


def test_the_tracker_on_plans_made_at_every_call_is_the_inline_reference():
    """With the planner handed every call's inputs before the call (plan_period so long that the
    thread itself makes none), the threaded reference equals the inline one: the same class, the
    same continuity offset, q, qd, qdd to 1e-12, off the millisecond grid too."""
    inline = toy_policy(nearest_k=8)
    threaded = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
    envs = walk(300)
    ts = [i * 1e-3 for i in range(250)] + [
        0.25 + 0.0173 * i for i in range(50)
    ]  # off the grid at the end
    q0 = torch.tensor([0.1, -0.2], dtype=F64)
    for pol in (inline, threaded):
        pol.reset()
    labels = set()
    for i, t in enumerate(ts):
        q = q0 if i == 0 else None
        if i > 0:  # the planner's step on this call's inputs
            with threaded._planner.lock:
                threaded._planner.plan = threaded._plan(
                    threaded._motion, envs[i].numpy(), t, None, None
                )
        a, b = inline.reference(envs[i], t, q), threaded.reference(envs[i], t, q)
        assert a.label == b.label and b.plan_t == t
        labels.add(a.label)
        for x, y in zip(a[:3], b[:3]):
            torch.testing.assert_close(y, x, rtol=0, atol=1e-12)
    assert labels == {0, 1}  # a switch on the way
    threaded.close()


def test_the_tracker_never_waits_for_a_slow_planner(monkeypatch):
    """A planner that takes 60 ms a plan: every call returns at once with the newest plan, whose
    time lags behind the call's."""
    pol = toy_policy(nearest_k=8, planner="thread", plan_period=1e-3)
    slow = pol._plan

    def plan(*a):
        time.sleep(0.06)
        return slow(*a)

    pol._planner.make = plan
    envs = walk(200)
    pol.reset(envs[0])  # the first plan made here, at t = 0
    took, lag = [], []
    for i in range(200):
        t0 = time.perf_counter()
        r = pol.reference(envs[i], i * 1e-3)
        took.append(time.perf_counter() - t0)
        lag.append(i * 1e-3 - r.plan_t)
        time.sleep(1e-3)
    assert max(took) < 0.03  # never a whole plan's 60 ms (the shared machine's scheduling aside)
    assert lag[0] == 0.0 and max(lag) > 0.03  # the plans age while the planner works
    assert pol._planner.plans >= 1  # and the thread does publish
    pol.close()


def test_the_planner_keeps_up_and_ends_with_its_policy():
    """At 1 kHz for 0.3 s the thread publishes plans for the loop's inputs; a new motion drops the
    old one's plan; a policy nobody holds any more takes its thread down."""
    pol = toy_policy(nearest_k=8, planner="thread")  # plan_period: decision_dt / 4 = 5 ms
    envs = walk(300)
    pol.reset()
    ages = []
    for i in range(300):
        ages.append(i * 1e-3 - pol.reference(envs[i], i * 1e-3).plan_t)
        time.sleep(1e-3)
    assert pol._planner.plans >= 5 and sorted(ages)[150] < 0.1
    pol.reset()
    assert pol._planner.plan is None
    assert pol.reference(envs[0], 0.0).plan_t == 0.0  # the first call of a motion plans for itself
    thread = pol._planner._thread
    del pol
    gc.collect()
    thread.join(timeout=2.0)
    assert not thread.is_alive()


def test_bad_input_is_refused_before_any_work_in_thread_mode():
    pol = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
    with pytest.raises(ValueError, match="env must be"):
        pol.reference(torch.zeros(3, dtype=F64), 0.0)
    with pytest.raises(ValueError, match="env holds NaN"):
        pol.reference(torch.tensor([math.nan, 0.0]), 0.0)
    with pytest.raises(ValueError, match="t must be"):
        pol.reference(torch.zeros(2, dtype=F64), -1.0)
    with pytest.raises(ValueError, match="q must be"):
        pol.reference(torch.zeros(2, dtype=F64), 0.0, torch.zeros(3))
    with pytest.raises(ValueError, match="planner must be"):
        toy_policy(planner="fork")
    assert pol._planner.inbox is None  # nothing handed over
    pol.close()


def test_the_numpy_basis_is_the_policys():
    pol = toy_policy(nearest_k=8)
    P = pol._P
    for z in (0.0, 0.137, 0.5, 1.0):
        want = pol.basis_at(z * pol.duration).numpy() / pol._scale.numpy() if z < 1 else None
        got = basis3_np(P.centers.double().numpy(), float(P.width), z)
        if want is not None:
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def limiter() -> JerkLimiter:
    return JerkLimiter(*robot_limits(None, 7, **{k: v for k, v in FRANKA_JOINT_LIMITS.items()}))


def test_the_limiter_keeps_the_limits_and_gives_the_wanted_state_back():
    """A smooth wanted motion whose acceleration steps by up to 12 rad/s^2 (what the continuity
    offset does at a switch: position and velocity continuous; joint 2's 8 rad/s^2 beyond its 7.5):
    between ticks the velocity, acceleration and jerk stay within Franka's limits; Ruckig's
    hand-over meets the wanted motion (known ahead, as the tracker knows its plan's), after which
    the wanted state is sent exactly again."""
    lim = limiter()
    k = np.arange(7)
    a1 = np.linspace(
        -12.0, 12.0, 7
    )  # rad/s^2 added from t = 0.1 s on, taken back from t = 0.2 s on

    def wanted_at(t: float) -> np.ndarray:  # (3, D)
        s1, s2 = max(t - 0.1, 0.0), max(t - 0.2, 0.0)
        return np.stack(
            [
                0.3 * np.sin(t + k) + 0.5 * a1 * (s1**2 - s2**2),
                0.3 * np.cos(t + k) + a1 * (s1 - s2),
                -0.3 * np.sin(t + k) + a1 * ((t >= 0.1) - float(t >= 0.2)),
            ]
        )

    sent, wanted = [], []
    for i in range(600):
        t = i * 1e-3
        wanted.append(wanted_at(t))
        sent.append(lim.step(wanted[-1], 1e-3, lambda s, t0=t - 1e-3: wanted_at(t0 + s)))
    s, w = np.stack(sent), np.stack(wanted)  # (T, 3, D)
    assert (np.abs(s[:, 1]) <= lim.vmax * (1 + 1e-9)).all()
    assert (np.abs(s[:, 2]) <= lim.amax * (1 + 1e-9)).all()
    jerk = np.abs(np.diff(s[:, 2], axis=0)) / 1e-3  # (T - 1, D)
    assert (jerk <= lim.jmax * (1 + 1e-6)).all()
    assert jerk.max() > 0.99 * lim.jmax.max()  # the steps did need the limiter
    np.testing.assert_array_equal(s[:100], w[:100])  # nothing to limit before the first step
    np.testing.assert_array_equal(
        s[300:], w[300:]
    )  # the hand-over met the wanted motion: passed through again
    assert 0 < lim.following <= 3 and lim.failed == 0


def test_the_planner_holds_the_switch_interval_while_it_runs():
    """The first running planner thread lowers the switch interval to SWITCH_INTERVAL, the last
    one to stop puts back the one it found; an application's lower interval is kept, one it set
    meanwhile is not overwritten, a dropped policy gives it back too; process planners leave it."""
    found = sys.getswitchinterval()
    gc.collect()  # planners of dropped policies give it back when collected
    assert _SwitchInterval.running == 0
    try:
        sys.setswitchinterval(0.005)
        a = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
        b = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
        assert math.isclose(sys.getswitchinterval(), SWITCH_INTERVAL)
        a.close()
        a.close()  # once per planner
        assert math.isclose(sys.getswitchinterval(), SWITCH_INTERVAL)  # b still runs
        b.close()
        assert math.isclose(sys.getswitchinterval(), 0.005)

        sys.setswitchinterval(1e-4)  # lower already: kept
        c = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
        assert math.isclose(sys.getswitchinterval(), 1e-4)
        c.close()
        assert math.isclose(sys.getswitchinterval(), 1e-4)

        sys.setswitchinterval(0.005)
        d = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
        sys.setswitchinterval(0.002)  # the application's own, while the planner runs
        d.close()
        assert math.isclose(sys.getswitchinterval(), 0.002)

        sys.setswitchinterval(0.005)
        e = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
        assert math.isclose(sys.getswitchinterval(), SWITCH_INTERVAL)
        del e
        gc.collect()
        assert math.isclose(sys.getswitchinterval(), 0.005)
        assert _SwitchInterval.running == 0

        f = toy_policy(nearest_k=8, planner="process", plan_period=2e-3)
        assert math.isclose(sys.getswitchinterval(), 0.005)
        f.close()
    finally:
        sys.setswitchinterval(found)


def test_the_trackers_input_check_reads_tensors_arrays_and_lists_alike():
    """``_values``: the same floats from a float64 tensor, array or list and from a float32
    tensor (through ``as_array``); the same errors; finite values whose sum overflows pass."""
    x = [0.25, -1.5, 3.0]
    for given in (
        torch.tensor(x, dtype=F64),
        np.array(x),
        x,
        torch.tensor(x, dtype=torch.float32),
    ):
        got = _values(given, 3, "q")
        assert type(got) is list and got == x and got is not given
    assert _values(None, 3, "q") is None
    assert _values(torch.tensor([1e308, 1e308, -1e308], dtype=F64), 3, "q") == [
        1e308,
        1e308,
        -1e308,
    ]
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="q holds NaN or inf"):
            _values(torch.tensor([0.0, bad, 1.0], dtype=F64), 3, "q")
        with pytest.raises(ValueError, match="q holds NaN or inf"):
            _values(np.array([0.0, bad, 1.0]), 3, "q")
    with pytest.raises(ValueError, match=r"q must be \(3,\) values, got shape \(3, 1\)"):
        _values(torch.zeros(3, 1, dtype=F64), 3, "q")
    with pytest.raises(ValueError, match=r"q must be \(3,\) values, got shape \(2,\)"):
        _values(np.zeros(2), 3, "q")


def test_the_trackers_products_are_the_matmuls_bit_for_bit():
    """``Tracker.step`` against the offset written out: the same bits at every call, through plan
    changes, off the millisecond grid too."""
    g = np.random.default_rng(0)
    kb, d, duration, blend = 10, 7, 2.0, 10.0
    centers, width = np.linspace(0.0, 1.0, kb), 0.08
    phi_ms = np.stack(
        [
            basis3_np(centers, width, i * 1e-3 / duration)
            * np.array([1.0, 1 / duration, 1 / duration**2])[:, None]
            for i in range(int(duration * 1000) + 1)
        ]
    )  # (T_ms + 1, 3, Kb)
    tr = Tracker(phi_ms, centers, width, duration, blend)
    plans = [Plan(g.standard_normal((kb, d)), c % 2, 0.0, 0) for c in range(6)]
    q0 = g.standard_normal(d)
    at_jump = decay_np(blend, 0.0)  # (3, 2)
    off, last, last_t = None, None, 0.0
    for i in range(600):
        t = i * 1e-3 + (3.7e-4 if i % 50 == 7 else 0.0)
        plan = plans[(i // 97) % len(plans)]
        got = tr.step(t, plan, q0 if i == 0 else None, None)
        phi = tr.basis(t)  # (3, Kb)
        want = phi @ plan.W  # (3, D)
        if last is None:
            jump = np.stack([q0, 0.0 * q0]) - want[:2]
        else:
            jump = phi[:2] @ (last.W - plan.W) if plan is not last else None
        if off is not None:
            off = decay_np(blend, t - last_t)[:2] @ off
            if jump is not None:
                off += jump
        else:
            off = jump
        want += at_jump @ off
        last, last_t = plan, t
        assert np.array_equal(got, want), i
