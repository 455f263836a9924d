"""The robot's limits joint by joint (:class:`~protorch.policy.limits.JointwiseLimiter`): the
same per-joint limits as :class:`~protorch.policy.limits.JerkLimiter`, each joint handed over on
its own, so a joint with a small jump is back on the wanted motion before the slowest one; the
policy's ``limits`` (:func:`~protorch.policy.limits.make_limiter`): on by default for the
two-rate planners, off inline, bad values refused."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from protorch.policy.limits import JerkLimiter, JointwiseLimiter, make_limiter
from protorch.robots.published import FRANKA_JOINT_LIMITS

LIMITS = [
    np.array(FRANKA_JOINT_LIMITS[k]) for k in ("max_velocity", "max_acceleration", "max_jerk")
]
GAIN = np.linspace(0.2, 1.0, 7)  # (D,) each joint's velocity jump (rad/s)


def wanted(t: float) -> np.ndarray:
    """A motion at rest whose velocity steps at 0.05 s (a class switch's new plan): ``(3, D)``."""
    s = max(t - 0.05, 0.0)
    return np.stack([s * GAIN, (t >= 0.05) * GAIN, np.zeros(7)])


def run(limiter, steps: int = 400, dt: float = 1e-3) -> np.ndarray:
    out = []
    for k in range(steps):
        t = k * dt
        out.append(
            limiter.step(wanted(t), dt if k else 0.0, lambda s, t=t: wanted(t - dt + s), False)
        )
    return np.stack(out)  # (T, 3, D)


def test_jointwise_hand_overs_keep_the_limits_and_free_the_fast_joints():
    vmax, amax, jmax = LIMITS
    sync, each = run(JerkLimiter(*LIMITS)), run(JointwiseLimiter(*LIMITS))
    for x in (sync, each):
        jerk = np.abs(np.diff(x[:, 2], axis=0)) / 1e-3
        assert (np.abs(x[:, 1]) <= vmax * (1 + 1e-9)).all()
        assert (np.abs(x[:, 2]) <= amax * (1 + 1e-9)).all()
        assert (jerk <= jmax * (1 + 1e-6)).all()
        np.testing.assert_allclose(x[-1], wanted(0.399), atol=1e-9)  # back on the motion

    def back(x):  # per joint, the first tick from which the wanted state is sent
        want = np.stack([wanted(k * 1e-3) for k in range(x.shape[0])])
        off = np.abs(x - want).max(axis=1) > 1e-9  # (T, D)
        return np.array([np.nonzero(off[:, i])[0].max() + 1 for i in range(7)])

    b_sync, b_each = back(sync), back(each)
    assert len(set(b_sync.tolist())) == 1  # synchronised: every joint rejoins at once
    assert (b_each <= b_sync).all() and b_each[0] < b_sync[0]  # the smallest jump rejoins first


def test_jointwise_limits_are_checked():
    with pytest.raises(ValueError, match="one value per joint"):
        JointwiseLimiter([1.0, 2.0], [1.0], [1.0, 2.0])


# ----------------------------------------------------------------- the policy's default


def test_the_two_rate_planners_are_limited_by_default_and_inline_is_not():
    """``limits="auto"`` (the default): joint by joint with the robot's limits for the thread and
    process planners, none inline or without a robot's limits; ``True`` is joint by joint,
    ``"together"`` synchronised, ``False`` none."""
    panda = SimpleNamespace(**FRANKA_JOINT_LIMITS)
    for planner in ("thread", "process"):
        lim = make_limiter("auto", planner, panda, 7)
        assert type(lim) is JointwiseLimiter
        for got, want in zip((lim.vmax, lim.amax, lim.jmax), LIMITS):
            np.testing.assert_array_equal(got, want)
        assert make_limiter(False, planner, panda, 7) is None
        assert type(make_limiter(True, planner, panda, 7)) is JointwiseLimiter
        assert type(make_limiter("joint", planner, panda, 7)) is JointwiseLimiter
        assert type(make_limiter("together", planner, panda, 7)) is JerkLimiter
        assert make_limiter("auto", planner, None, 7) is None  # no robot: nothing to hold to
        given = make_limiter("auto", planner, None, 2, max_velocity=1.0, max_acceleration=2.0)
        np.testing.assert_array_equal(given.amax, [2.0, 2.0])
    assert make_limiter("auto", "inline", panda, 7) is None
    assert make_limiter(False, "inline", panda, 7) is None


@pytest.mark.parametrize("bad", ["yes", "on", 1, 0, None, "Joint"])
def test_bad_limits_are_refused(bad):
    with pytest.raises(ValueError, match="limits must be 'auto', true, false"):
        make_limiter(bad, "thread", SimpleNamespace(**FRANKA_JOINT_LIMITS), 7)


def test_a_limiter_inline_and_a_bad_limit_are_refused():
    panda = SimpleNamespace(**FRANKA_JOINT_LIMITS)
    for limits in (True, "joint", "together"):
        with pytest.raises(ValueError, match="needs planner='thread' or 'process'"):
            make_limiter(limits, "inline", panda, 7)
    with pytest.raises(ValueError, match="max_velocity: the robot states none"):
        make_limiter(True, "thread", None, 7)
    with pytest.raises(ValueError, match="max_jerk must be a number or 7 numbers"):
        make_limiter("auto", "thread", panda, 7, max_jerk=-1.0)


def test_the_policy_refuses_bad_limits_before_any_work():
    from tests.control.test_policy import toy_policy

    with pytest.raises(ValueError, match="limits must be 'auto', true, false"):
        toy_policy(planner="thread", limits="sometimes", warm_up=False)
    with pytest.raises(ValueError, match="needs planner='thread'"):
        toy_policy(limits=True, warm_up=False)


def _ticks(pol, envs, q, qd, every: int = 5) -> np.ndarray:
    """``pol``'s reference at every 1 ms tick of one episode (``envs (T+1, 4)``, ``q, qd (T+1,
    D)`` at the 20 ms control steps), a plan made every ``every`` ticks on that tick's inputs
    (the planner thread's rhythm, made deterministic); inline: every call plans. ``(ticks, 3,
    D)`` and the labels."""
    per = 20
    if pol.planner == "inline":
        pol.reset()
    else:  # the motion's first plan, at t = 0
        pol.reset(envs[0], q[0], qd[0])
    states, labels = [], []
    for i in range((envs.shape[0] - 1) * per + 1):
        s, t = i // per, i * 1e-3
        if pol.planner != "inline" and i and i % every == 0:
            with pol._planner.lock:
                pol._planner.plan = pol._plan(
                    pol._motion, envs[s].numpy(), t, q[s].numpy(), qd[s].numpy()
                )
        r = pol.reference(envs[s], t, q[s], qd[s])
        states.append(torch.stack([r.q, r.qd, r.qdd]).numpy())
        labels.append(r.label)
    return np.stack(states), np.array(labels)


def _ratios(x: np.ndarray, lim, tick: float = 1e-3) -> np.ndarray:
    """The largest ``|qd| / vmax``, ``|qdd| / amax``, ``|qdd_t - qdd_{t-1}| / (tick jmax)``,
    ``|q_t - q_{t-1}| / (tick vmax)`` and ``|qd_t - qd_{t-1}| / (tick amax)`` over ``x (T, 3,
    D)``: the last three finite differences at the tick."""
    vmax, amax, jmax = lim
    d = np.diff(x, axis=0) / tick  # (T-1, 3, D)
    return np.array(
        [
            (np.abs(x[:, 1]) / vmax).max(),
            (np.abs(x[:, 2]) / amax).max(),
            (np.abs(d[:, 2]) / jmax).max(),
            (np.abs(d[:, 0]) / vmax).max(),
            (np.abs(d[:, 1]) / amax).max(),
        ]
    )


@pytest.mark.slow  # IK demonstrations and an arm map (tests/policy/builders.py)
def test_the_default_threaded_reference_keeps_the_limits_and_inline_is_unchanged():
    """The two-class arm map's moving-test episodes (random moves of the can and the target,
    class switches) with an environment jump added (the can thrown 8 cm across at 0.6 s), at
    1 kHz: the threaded policy *as it comes* (no ``limits`` given) keeps the Panda's velocity,
    acceleration and jerk limits at every tick (the finite differences of position, velocity
    and acceleration at the tick within them too); the same with ``limits=False`` asks for more
    (the check is not vacuous); the inline policy as it comes has no limiter and gives bit for
    bit what ``limits=False`` gives."""
    from protorch.policy.limits import robot_limits

    from .builders import moving_episodes, two_class_arm_policy

    base = two_class_arm_policy(warm_up=False)
    res = moving_episodes(base)
    envs = res.envs.clone().to(torch.float64)  # (E, T+1, 4)
    envs[:, 30:, 1] += torch.where(envs[:, 30:31, 1] > 0, -0.08, 0.08)  # the jump, at 0.6 s
    kw = dict(
        task=base.task,
        duration=base.duration,
        switch_margin=base.switch_margin,
        decision_dt=base.decision_dt,
        switch_clearance=base.switch_clearance,
        warm_up=False,
    )
    limited = type(base)(
        base._P, base.env_map, base.task_name, planner="thread", plan_period=1e6, **kw
    )  # no limits given: the default
    free = type(base)(
        base._P, base.env_map, base.task_name, planner="thread", plan_period=1e6, limits=False, **kw
    )
    assert type(limited._limiter) is JointwiseLimiter and free._limiter is None
    lim = robot_limits(base.task.robot, 7)
    np.testing.assert_array_equal(limited._limiter.amax, [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
    inline, inline_off = base, type(base)(base._P, base.env_map, base.task_name, limits=False, **kw)
    assert inline._limiter is None and inline.planner == "inline"
    worst_on, worst_off, switches = np.zeros(5), np.zeros(5), 0
    for e in range(envs.shape[0]):
        q, qd = res.q[e].to(torch.float64), res.qd[e].to(torch.float64)
        x_on, lab = _ticks(limited, envs[e], q, qd)
        x_off, _ = _ticks(free, envs[e], q, qd)
        switches += int((np.diff(lab) != 0).sum())
        worst_on = np.maximum(worst_on, _ratios(x_on, lim))
        worst_off = np.maximum(worst_off, _ratios(x_off, lim))
        if e < 2:  # inline as it comes: bit for bit the unlimited inline reference
            a, la = _ticks(inline, envs[e], q, qd)
            b, lb = _ticks(inline_off, envs[e], q, qd)
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(la, lb)
    assert switches >= 1
    assert (worst_on <= 1 + 1e-9).all(), worst_on
    assert worst_off[1:3].max() > 1.5, worst_off  # unlimited: a switch, a jump ask for more
    free.close()
    limited.close()


class _EachJoint:
    """The joint-by-joint limiter spelled out: one :class:`JerkLimiter` per joint, stepped one
    after the other (what :class:`JointwiseLimiter` must equal, its all-joints pass-through
    included)."""

    def __init__(self, vmax, amax, jmax) -> None:
        self.joints = [
            JerkLimiter(vmax[i : i + 1], amax[i : i + 1], jmax[i : i + 1]) for i in range(len(vmax))
        ]

    def step(self, want, dt, future, changed=False):
        return np.concatenate(
            [
                lim.step(want[:, i : i + 1], dt, lambda s, i=i: future(s)[:, i : i + 1], changed)
                for i, lim in enumerate(self.joints)
            ],
            axis=1,
        )


def test_the_all_joints_pass_through_equals_each_joint_s_limiter_bit_for_bit():
    """A wandering motion with velocity steps (class switches), a position jump (an environment
    jump), new motions (``changed``) and irregular ticks (0, 1, 2 ms): JointwiseLimiter's output
    equals the per-joint limiters' bit for bit, with hand-overs under way and without."""
    rng = np.random.default_rng(0)
    steps = [0.0] + rng.choice([0.0, 1e-3, 1e-3, 1e-3, 2e-3], 1499).tolist()
    jumps = {300: 0.4, 700: -0.8, 1100: 0.3}  # tick -> a velocity step on every joint
    freq = rng.uniform(0.5, 2.0, 7)  # (D,)

    def motion(t: float, k: int) -> np.ndarray:  # (3, D)
        base = sum(v for j, v in jumps.items() if k >= j)
        pos = 0.3 * np.sin(freq * t) + base * t * GAIN + (0.02 if k >= 900 else 0.0)
        vel = 0.3 * freq * np.cos(freq * t) + base * GAIN
        return np.stack([pos, vel, -0.3 * freq**2 * np.sin(freq * t)])

    fast, slow = JointwiseLimiter(*LIMITS), _EachJoint(*LIMITS)
    t = 0.0
    for k, dt in enumerate(steps):
        t += dt
        want = motion(t, k)
        changed = k in (500, 1300)
        a = fast.step(want, dt, lambda s, t=t, k=k: motion(t - dt + s, k), changed)
        b = slow.step(want, dt, lambda s, t=t, k=k: motion(t - dt + s, k), changed)
        np.testing.assert_array_equal(a, b, err_msg=f"tick {k}")
    assert fast.following == sum(j.following for j in slow.joints) > 0  # hand-overs happened


@pytest.mark.parametrize("make", [JerkLimiter, JointwiseLimiter])
def test_a_motion_accelerating_into_the_velocity_limit_keeps_it(make):
    """The wanted velocity ramps at 12 rad/s^2 into the Panda's 2.175 rad/s and stops there (an
    acceleration step the jerk limit forbids). A state at 2.172 rad/s still accelerating at 12
    passed the step's tests but could not be followed within the limit (0.28% over, before): the
    limiter now leaves the motion early enough and never exceeds the velocity limit."""
    vmax, amax, jmax = np.array([2.175]), np.array([15.0]), np.array([7500.0])
    a0, t1 = 12.0, 2.175 / 12.0

    def ramp(t: float) -> np.ndarray:  # (3, 1)
        q = 0.5 * a0 * min(t, t1) ** 2 + vmax[0] * max(t - t1, 0.0)
        return np.array([[q], [min(a0 * t, vmax[0])], [a0 if t < t1 else 0.0]])

    lim, out = make(vmax, amax, jmax), []
    for k in range(400):
        t = k * 1e-3
        out.append(lim.step(ramp(t), 1e-3 if k else 0.0, lambda s, t=t: ramp(t - 1e-3 + s)))
    x = np.stack(out)  # (T, 3, 1)
    assert lim.following > 0  # the hand-over happened
    assert (np.abs(x[:, 1]) <= vmax * (1 + 1e-9)).all()
    assert (np.abs(x[:, 2]) <= amax * (1 + 1e-9)).all()
    assert (np.abs(np.diff(x[:, 2], axis=0)) <= jmax * 1e-3 * (1 + 1e-6)).all()
    # back on the motion's velocity and acceleration; its position behind by what leaving the
    # ramp early cost (at the velocity limit it cannot be made up)
    np.testing.assert_allclose(x[-1, 1:], ramp(0.399)[1:], atol=1e-9)
    assert 0.0 <= ramp(0.399)[0, 0] - x[-1, 0, 0] < 1e-5


def _meetings(bias_after: float, grid: bool = True):
    """One joint: a velocity step at 50 ms (a hand-over), and at 55 ms a new plan of the same
    class (``changed``, ``near``) whose velocity step is ``0.8 + bias_after``; every tick checked
    against the limits. The hand-over's meeting time (s) after each tick where one is under way,
    and the limiter."""
    vmax, amax, jmax = (x[:1] for x in LIMITS)

    def motion(t: float, bias: float) -> np.ndarray:  # (3, 1)
        s = max(t - 0.05, 0.0)
        return np.array([[s * (0.8 + bias)], [(t >= 0.05) * (0.8 + bias)], [0.0]])

    def meet_ms(t0: float):
        return lambda s: np.ceil(round((t0 + s) * 1e3, 9)) * 1e-3 - t0

    lim, out, meets = JerkLimiter(vmax, amax, jmax), [], []
    for k in range(300):
        t, bias = k * 1e-3, (bias_after if k >= 55 else 0.0)
        t0 = t - 1e-3
        out.append(
            lim.step(
                motion(t, bias),
                1e-3 if k else 0.0,
                lambda s, t0=t0, bias=bias: motion(t0 + s, bias),
                changed=k == 55,
                meet=meet_ms(t0) if grid else None,
                near=True,
            )
        )
        if lim._join is not None:
            meets.append(t + lim._join - lim._elapsed)
    x = np.stack(out)
    assert (np.abs(x[:, 1]) <= vmax * (1 + 1e-9)).all()
    assert (np.abs(x[:, 2]) <= amax * (1 + 1e-9)).all()
    assert (np.abs(np.diff(x[:, 2], axis=0)) <= jmax * 1e-3 * (1 + 1e-6)).all()
    np.testing.assert_allclose(x[-1], motion(0.299, bias_after), atol=1e-12)  # back on it
    return meets, lim


def test_a_hand_over_meets_on_the_grid_and_a_new_plan_keeps_its_meeting_where_it_can():
    """With ``meet`` (the tracker's whole milliseconds) a hand-over's meeting lies on the grid;
    re-planned for the same motion (a new plan of the same class, ``near``) it keeps its meeting
    time; re-planned for a motion it can meet sooner it meets sooner, not at the old time (a
    later meeting than the first possible one stretches Ruckig's profile, which can swing the
    joint away and back: the example loop's arm hit the can that way); without ``meet`` the
    meeting is Ruckig's own time (off the grid). Every tick within the limits."""
    same, lim = _meetings(0.0)
    assert lim.following == 2 and same[0] > 0.06  # hand-overs at 50 ms and at 55 ms
    assert abs(same[0] * 1e3 - round(same[0] * 1e3)) < 1e-9
    assert abs(same[-1] - same[0]) < 1e-12
    sooner, _ = _meetings(-0.3)  # the new plan asks for a smaller velocity step
    assert sooner[0] == same[0] and sooner[-1] < sooner[0] - 0.01
    free, _ = _meetings(0.0, grid=False)
    assert abs(free[0] * 1e3 - round(free[0] * 1e3)) > 1e-6
