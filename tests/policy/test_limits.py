"""The robot's limits joint by joint (:class:`~protorch.policy.limits.JointwiseLimiter`): the
same per-joint limits as :class:`~protorch.policy.limits.JerkLimiter`, each joint handed over on
its own, so a joint with a small jump is back on the wanted motion before the slowest one."""

from __future__ import annotations

import numpy as np
import pytest

from protorch.policy.limits import JerkLimiter, JointwiseLimiter
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
