"""The shared episode runner (protorch.control.episodes): the time grid and its step cap, the
stability bounds of the semi-implicit Euler step (against the spectral radius of the step
matrix), and the time loop against a hand-written one."""

from __future__ import annotations

import itertools

import pytest
import torch

from protorch.control.episodes import (
    MAX_STEPS,
    check_pd_stable,
    check_timing,
    check_velocity_loop_stable,
    episode_walk,
    hold_last,
    promp_state_at,
    track,
)
from protorch.primitives.promp import ProMP

F64 = torch.float64


def test_timing_counts_moving_and_held_steps():
    t = check_timing(0.01, 2.0, 0.5)
    assert (t.moving, t.held, t.total) == (200, 50, 250)
    assert t.phase(0) == 0.0 and t.phase(100) == pytest.approx(0.5) and t.phase(240) == 1.0
    assert t.hold == pytest.approx(0.5)


def test_step_cap_is_refused_with_the_bound():
    ok = check_timing(2.5 / MAX_STEPS, 2.0, 0.5)  # exactly at the cap
    assert ok.total == MAX_STEPS
    with pytest.raises(
        ValueError, match=r"control steps per episode.*limit of 1000000.*dt >= 2\.5e-06"
    ):
        check_timing(1e-6, 2.0, 0.5)


def pd_step_matrix(kp, kd, mass, dt):
    """One semi-implicit Euler step of e'' = -(kp e + kd e') / mass on (e, v)."""
    k, c = kp / mass, kd / mass
    return torch.tensor([[1 - k * dt * dt, dt * (1 - c * dt)], [-k * dt, 1 - c * dt]], dtype=F64)


def test_pd_bound_is_where_the_step_matrix_becomes_unstable():
    grid = itertools.product(
        [1.0, 100.0, 1000.0, 1e4, 1e6],
        [0.5, 30.0, 300.0],
        [0.5, 1.0, 3.0],
        [1e-4, 1e-3, 0.01, 0.05, 0.1],
    )
    refused = stable = 0
    for kp, kd, mass, dt in grid:
        radius = float(torch.linalg.eigvals(pd_step_matrix(kp, kd, mass, dt)).abs().max())
        if radius < 1 - 1e-9:
            check_pd_stable(kp, kd, mass, dt)  # must not raise
            stable += 1
        elif radius > 1 + 1e-9:
            with pytest.raises(
                ValueError, match="dt = .* kp = .*kp dt\\^2 / mass \\+ 2 kd dt / mass < 4"
            ):
                check_pd_stable(kp, kd, mass, dt)
            refused += 1
    assert stable > 20 and refused > 20  # both sides of the bound are exercised


def test_velocity_loop_bound():
    check_velocity_loop_stable(10.0, 0.02)
    check_velocity_loop_stable(99.0, 0.02)
    for kp, dt in [(100.0, 0.02), (10.0, 0.5)]:
        with pytest.raises(ValueError, match=r"dt = .* kp = .*kp dt < 2"):
            check_velocity_loop_stable(kp, dt)


def test_walk_or_env0():
    t = check_timing(0.1, 1.0, 0.2)
    assert episode_walk(torch.zeros(3, 2), None, t, 2) is None
    w = torch.zeros(3, 11, 2)
    assert episode_walk(None, w, t, 2) is w
    with pytest.raises(ValueError, match="not both"):
        episode_walk(torch.zeros(3, 2), w, t, 2)
    with pytest.raises(ValueError, match=r"give env0 \(E, 2\)"):
        episode_walk(None, None, t, 2)
    with pytest.raises(ValueError, match=r"walk must be \(E, 11, 2\)"):
        episode_walk(None, torch.zeros(0, 11, 2), t, 2)
    held = hold_last(torch.arange(6.0).reshape(1, 3, 2), 2)
    assert held.shape == (1, 5, 2) and bool((held[0, 2:] == torch.tensor([4.0, 5.0])).all())


class Spring:
    """A fixed mean for every episode; a spring-damper towards the marker; records its calls."""

    def __init__(self, w):
        self.w, self.seen = w, []

    def answer(self, t, z, x, v=None):
        self.seen.append((t, z, x.clone()))
        return self.w

    def acceleration(self, x, v, m, m_vel):
        return 50.0 * (m - x) + 5.0 * (m_vel - v)


def test_track_matches_a_hand_written_loop():
    p = ProMP(2, 5, 40)
    g = torch.Generator().manual_seed(0)
    w = torch.randn(3, p.num_weights, generator=g, dtype=F64)  # (E, N)
    t = check_timing(0.05, 1.0, 0.2)
    sys_ = Spring(w)
    run = track(sys_, p, t, 3, None)
    assert run.positions.shape == (3, t.total + 1, 2) and run.weights.shape == (
        3,
        t.total + 1,
        p.num_weights,
    )
    assert [s[0] for s in sys_.seen] == list(range(t.total + 1))  # one answer per instant
    x = v = None
    for k in range(t.total + 1):
        z = min(k * 0.05, 1.0)
        m, dm = promp_state_at(p, w, z)
        mv = dm / 1.0 if k < t.moving else torch.zeros_like(m)
        assert torch.equal(run.markers[:, k], m)
        if k == 0:
            x, v = m.clone(), torch.zeros_like(m)  # starts at rest on the first marker
        assert torch.equal(run.positions[:, k], x) and torch.equal(run.velocities[:, k], v)
        v = v + (50.0 * (m - x) + 5.0 * (mv - v)) * 0.05
        x = x + v * 0.05
    start = torch.tensor([1.0, 2.0], dtype=F64)
    quiet = track(Spring(w), p, t, 3, start, record=False)
    assert quiet.markers is None and quiet.weights is None
    assert bool((quiet.positions[:, 0] == start).all()) and bool(
        (quiet.velocities[:, 0] == 0).all()
    )
