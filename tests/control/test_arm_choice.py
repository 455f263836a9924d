"""The arm's class choice with the plan check: a blocked class is passed over while another is
clear (hysteresis_choice: every class blocked leaves the choice to the scores, and the hysteresis
still holds; checked_choice then takes the plan with the largest clearance), and the plan's way
over is the path the moving test's velocity command drives."""

from __future__ import annotations

import math

import torch

from protorch.control.arm_choice import hysteresis_choice


def test_a_blocked_class_is_passed_over_while_another_is_clear():
    scores = torch.tensor(
        [[0.1, 0.1, 0.5], [0.3, 0.3, 0.2]]
    )  # (K=2, E=3): class 0 is cheaper for e = 0, 1
    blocked = torch.tensor([[True, False, False], [False, False, False]])
    assert hysteresis_choice(scores, None, 0.0).tolist() == [0, 0, 1]
    assert hysteresis_choice(scores, None, 0.0, blocked).tolist() == [1, 0, 1]
    # the current class blocked: left whatever the margin
    assert hysteresis_choice(scores, torch.tensor([0, 0, 1]), 10.0, blocked).tolist() == [1, 0, 1]


def test_every_class_blocked_leaves_the_choice_to_the_scores_and_the_hysteresis():
    scores = torch.tensor([[0.10, 0.4], [0.12, 0.2]])  # (K=2, E=2)
    blocked = torch.ones(2, 2, dtype=torch.bool)
    assert hysteresis_choice(scores, None, 0.0, blocked).tolist() == [0, 1]
    # within the margin the current class stays
    assert hysteresis_choice(scores, torch.tensor([1, 0]), 0.05, blocked).tolist() == [1, 1]
    assert hysteresis_choice(scores, torch.tensor([1, 0]), 0.5, blocked).tolist() == [1, 0]


def _tracked(task, promp, w, steps, kp=10.0, dt=0.02, duration=1.0):
    """The moving test's arm (velocity command, semi-implicit Euler of track()) on one fixed mean
    ``w (E, N)`` from the start configuration: positions and velocities ``(E, steps + 1, J)``."""
    from protorch.control.arm_choice import velocity_command_acceleration
    from protorch.control.episodes import Timing, track

    class Fixed:
        def answer(self, t, z, q, qd=None):
            return w

        def acceleration(self, q, qd, m, m_vel):
            return velocity_command_acceleration(
                q,
                qd,
                m,
                m_vel,
                kp=kp,
                vmax=task.kinematics.max_velocity.to(q),
                amax=torch.as_tensor(task.robot.max_acceleration).to(q).expand(task.num_dof),
                dt=dt,
            )

    timing = Timing(
        dt=dt, duration=duration, moving=round(duration / dt), held=steps - round(duration / dt)
    )
    run = track(
        Fixed(), promp, timing, w.shape[0], task.start_config(dtype=torch.float64), record=False
    )
    return run.positions, run.velocities, timing


def test_the_plan_check_rolls_out_the_velocity_command_that_drives_the_arm():
    """rest_plan's way over with ``follow``: from the arm's state at an instant, the positions the
    moving test's own loop (track() with the velocity command) reaches at the next instants,
    every other one kept, while the mean and the environment stay; then the mean itself."""
    from protorch import ProMP
    from protorch.control.arm import arm_follow
    from protorch.control.arm_choice import rest_plan
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(cost_steps=6)
    promp = ProMP(task.num_dof, 10, 50)
    g = torch.Generator().manual_seed(0)
    start = task.start_config(dtype=torch.float64)
    w = (
        start[:, None] + 0.4 * torch.randn(2, task.num_dof, 10, generator=g, dtype=torch.float64)
    ).flatten(1)  # (2, N)
    pos, vel, timing = _tracked(task, promp, w, steps=70)
    follow = arm_follow(task, 10.0, task.robot.max_acceleration, timing)
    rest = torch.linspace(0.1, 1.0, 10, dtype=torch.float64)
    for t in (3, 20, 45):  # one whose rollout ends in the hold (z = 1 from t = 50)
        z = timing.phase(t)
        plan = rest_plan(promp, w[None], pos[:, t], z, rest, vel[:, t], follow)[0]  # (E, P, J)
        h = follow.horizon
        kept = [0] + [i + 1 for i in range(h) if i % 2 == 0 or i == h - 1]
        torch.testing.assert_close(
            plan[:, : len(kept)], pos[:, [t + i for i in kept]], rtol=0, atol=1e-12
        )
        later = rest[rest > min(z + h * timing.dt / timing.duration, 1.0)]
        torch.testing.assert_close(
            plan[:, len(kept) :], promp.trajectory(w, phase=later), rtol=0, atol=0
        )
    # without the velocities: the straight way over to the mean at z (8 points), then the mean
    plan = rest_plan(promp, w[None], pos[:, 3], timing.phase(3), rest)[0]
    assert plan.shape[1] == 9 + rest.numel()
    torch.testing.assert_close(plan[:, 0], pos[:, 3])


def test_where_every_class_is_blocked_the_largest_clearance_is_chosen():
    """checked_choice: a clear class is taken over a blocked one; where every class's plan is
    blocked, the class whose plan keeps the largest gap (rest_clearance), whatever the scores."""
    from protorch import ProMP
    from protorch.control.arm_choice import checked_choice, rest_blocked, rest_clearance
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(cost_steps=6, collision="volume")
    promp = ProMP(task.num_dof, 10, 50)
    start = task.start_config(dtype=torch.float64)
    g = torch.Generator().manual_seed(3)
    means = (
        start[:, None]
        + 0.3 * torch.randn(2, 40, task.num_dof, 10, generator=g, dtype=torch.float64)
    ).flatten(2)
    ee = task.kinematics.ee_position(
        promp.trajectory(means.flatten(0, 1), phase=torch.tensor([0.5], dtype=torch.float64))
    )
    env = torch.cat(
        [ee[:40, 0, :2], task.sample_envs(40, g)[:, 2:]], -1
    )  # the can under class 0's mean at z = 0.5
    env[20:, :2] = ee[40 + 20 :, 0, :2]  # and under class 1's for the last 20 systems
    rest = torch.linspace(0.3, 1.0, 8, dtype=torch.float64)
    now = start.expand(40, -1)
    scores = torch.stack([torch.zeros(40), torch.ones(40)]).to(
        torch.float64
    )  # class 0 always scored better
    blocked = rest_blocked(task, promp, means, env, now, 0.2, rest)  # (K, E)
    gaps = rest_clearance(task, promp, means, env, now, 0.2, rest)  # (K, E)
    assert torch.equal(blocked, gaps <= task.margin)
    c = checked_choice(task, promp, means, env, now, 0.2, rest, scores, None, 0.0)
    stuck = blocked.all(0)
    assert bool(stuck.any()) and bool((blocked[0] & ~blocked[1]).any())
    assert torch.equal(c[stuck], gaps[:, stuck].argmax(0))
    assert bool((c[blocked[0] & ~blocked[1]] == 1).all()) and bool((c[~blocked[0]] == 0).all())


def test_the_checks_hysteresis_takes_another_class_only_clear_by_the_extra_clearance():
    """checked_choice's ``switch_clearance``: a class other than the tracked one counts as clear
    only with ``margin + switch_clearance`` to spare (no flicker when its gap hovers at the
    margin), the tracked class keeps ``margin``; a blocked tracked class is still left for a class
    clear of the margin alone; where every class is blocked another class is taken only with a gap
    larger by half of ``switch_clearance``; 0 (or no tracked class yet) is the check without it."""
    from protorch import ProMP
    from protorch.control.arm_choice import checked_choice, rest_clearance
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(cost_steps=6, collision="volume")
    promp = ProMP(task.num_dof, 10, 50)
    start = task.start_config(dtype=torch.float64)
    g = torch.Generator().manual_seed(3)
    n = 400
    means = (
        start[:, None] + 0.3 * torch.randn(2, n, task.num_dof, 10, generator=g, dtype=torch.float64)
    ).flatten(2)
    ee = task.kinematics.ee_position(
        promp.trajectory(means[0], phase=torch.tensor([0.5], dtype=torch.float64))
    )
    env = torch.cat(
        [
            ee[:, 0, :2] + 0.08 * torch.randn(n, 2, generator=g, dtype=torch.float64),
            task.sample_envs(n, g)[:, 2:],
        ],
        -1,
    )  # the can near class 0's mean at z = 0.5
    rest = torch.linspace(0.3, 1.0, 8, dtype=torch.float64)
    now = start.expand(n, -1)
    gaps = rest_clearance(task, promp, means, env, now, 0.2, rest)  # (K, E)
    scores = torch.stack([torch.zeros(n), torch.ones(n)]).to(
        torch.float64
    )  # class 0 scored far better
    current = torch.ones(n, dtype=torch.long)  # the arm tracks class 1
    delta, m = 0.01, task.margin
    plain = checked_choice(task, promp, means, env, now, 0.2, rest, scores, current, 0.0)
    held = checked_choice(
        task, promp, means, env, now, 0.2, rest, scores, current, 0.0, switch_clearance=delta
    )
    assert torch.equal(
        plain,
        checked_choice(
            task, promp, means, env, now, 0.2, rest, scores, current, 0.0, switch_clearance=0.0
        ),
    )
    assert torch.equal(
        plain,
        checked_choice(
            task, promp, means, env, now, 0.2, rest, scores, None, 0.0, switch_clearance=delta
        ),
    )
    hover = (gaps[0] > m) & (gaps[0] <= m + delta)  # class 0 clear, but by less than the extra
    far = gaps[0] > m + delta
    assert int((hover & (gaps[1] > m)).sum()) >= 3 and int((hover & (gaps[1] <= m)).sum()) >= 1
    assert bool(
        (plain[gaps[0] > m] == 0).all()
    )  # without it: class 0 taken back as soon as it is clear
    assert bool((held[hover & (gaps[1] > m)] == 1).all())  # with it: the tracked class is kept
    assert bool((held[hover & (gaps[1] <= m)] == 0).all())  # but never a blocked one
    assert bool((held[far] == 0).all())
    # every class blocked: without it the largest gap; with it class 0 only where larger by delta
    stuck = (gaps <= m).all(0)
    assert int(stuck.sum()) >= 3
    assert torch.equal(plain[stuck], gaps[:, stuck].argmax(0))
    assert torch.equal(held[stuck], (gaps[0, stuck] > gaps[1, stuck] + delta / 2).long().neg() + 1)
    assert bool((held[stuck] != plain[stuck]).any())
    assert torch.equal(held[~hover & ~stuck], plain[~hover & ~stuck])


def test_the_rollout_of_a_few_systems_on_floats_is_the_tensor_loop_to_the_bit(monkeypatch):
    """rest_plan rolls out a policy's few systems on Python floats (FLOAT_ROWS): the same numbers
    to the bit as the tensor loop, with the velocity and the acceleration limits both active."""
    from protorch import ProMP
    from protorch.control import arm_choice
    from protorch.control.arm import arm_follow
    from protorch.control.arm_choice import rest_plan
    from protorch.control.episodes import Timing
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(cost_steps=6)
    promp = ProMP(task.num_dof, 10, 50)
    g = torch.Generator().manual_seed(1)
    timing = Timing(dt=0.02, duration=1.0, moving=50, held=20)
    follow = arm_follow(task, 10.0, task.robot.max_acceleration, timing)
    w = 2.0 * torch.randn(
        2, 1, task.num_dof * 10, generator=g, dtype=torch.float64
    )  # (K, E, N) far from the arm
    q = torch.randn(1, task.num_dof, generator=g, dtype=torch.float64)
    qd = 3.0 * torch.randn(
        1, task.num_dof, generator=g, dtype=torch.float64
    )  # beyond the velocity limits
    rest = torch.linspace(0.1, 1.0, 10, dtype=torch.float64)
    kept = follow._replace(tables={})  # a policy's: the basis values kept per phase
    for z in (0.0, 0.3, 0.9):
        fast = rest_plan(promp, w, q, z, rest, qd, follow)  # (K, E, P, J) on floats
        monkeypatch.setattr(arm_choice, "FLOAT_ROWS", 0)
        slow = rest_plan(promp, w, q, z, rest, qd, follow)  # the tensor loop
        monkeypatch.setattr(arm_choice, "FLOAT_ROWS", 4)
        assert torch.equal(fast, slow)
        for _ in range(2):  # the tables made, then read back: the same plan to the bit
            assert torch.equal(rest_plan(promp, w, q, z, rest, qd, kept), fast)
    assert len(kept.tables) == 3
    free = follow._replace(
        vmax=torch.full_like(follow.vmax, math.inf), amax=torch.full_like(follow.amax, math.inf)
    )
    assert not torch.allclose(
        rest_plan(promp, w, q, 0.0, rest, qd, free), rest_plan(promp, w, q, 0.0, rest, qd, follow)
    )


def test_a_capsule_point_moves_by_at_most_the_reach_weighted_joint_change():
    """point_reach bounds how far a joint change moves any point of the arm's capsules:
    ``|p(q) - p(q')| <= sum_j reach_j |q_j - q'_j|`` for random configurations near and far."""
    from protorch.control.plan_memo import point_reach
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(collision="volume")
    kin, plan = task.kinematics, task.capsule_plan
    reach = point_reach(kin, plan)  # (J,)
    g = torch.Generator().manual_seed(3)
    lo, hi = kin.lower.to(torch.float64), kin.upper.to(torch.float64)
    q0 = lo + (hi - lo) * torch.rand(400, task.num_dof, generator=g, dtype=torch.float64)
    for scale in (1e-3, 0.1, 1.0):
        q1 = q0 + scale * torch.randn(q0.shape, generator=g, dtype=torch.float64)
        moved = (
            (kin.carry_points(q1, plan) - kin.carry_points(q0, plan)).norm(dim=-1).amax(-1)
        )  # (B,)
        bound = (q1 - q0).abs() @ reach  # (B,)
        assert bool((moved <= bound + 1e-12).all())
        assert float((moved / bound).max()) > 0.5  # and not loose everywhere


def test_the_clearance_memo_passes_only_plans_the_full_check_finds_clear():
    """ClearanceMemo: bounds kept from a full check, carried to nearby plans and a moved can,
    pass a plan only where every configuration's exact capsule gap exceeds the margin, and pass
    some (the plans a little away from the can)."""
    from protorch.control.plan_memo import ClearanceMemo, point_reach
    from protorch.tasks.arm.collision import capsule_ends, capsules_clear, capsules_gap
    from protorch.tasks.arm.reach import ArmReachTask

    task = ArmReachTask(collision="volume")
    kin, plan = task.kinematics, task.capsule_plan
    r = task.capsule_radii
    g = torch.Generator().manual_seed(4)
    start = task.start_config(dtype=torch.float64)
    memo = ClearanceMemo(point_reach(kin, plan))
    env = torch.tensor([[0.55, 0.0, 0.7, 0.0]], dtype=torch.float64)  # (1, 4)
    q = start + 0.2 * torch.randn(
        1, 20, task.num_dof, generator=g, dtype=torch.float64
    )  # (1, P, J)
    a, b = capsule_ends(kin, q, plan)
    _, lower = capsules_clear(
        a, b, r, env, task.can_radius, task.can_height, task.margin, with_lower=True
    )
    gap = capsules_gap(
        a[:, :, None], b[:, :, None], r, env[:, None], task.can_radius, task.can_height
    )  # (1, P)
    assert bool((lower <= gap + 1e-12).all())  # lower bounds of each configuration's gap
    memo.add(q, env, lower)
    passed = 0
    for i in range(200):
        step = (i % 20 + 1) * 2e-3
        q1 = q + step * torch.randn(q.shape, generator=g, dtype=torch.float64)
        env1 = env + torch.tensor([[step, -step, 0.0, 0.0]], dtype=torch.float64)
        if memo.surely_clear(q1, env1, task.margin):
            a1, b1 = capsule_ends(kin, q1, plan)
            assert (
                float(capsules_gap(a1, b1, r, env1, task.can_radius, task.can_height).min())
                > task.margin
            )
            passed += 1
    assert 0 < passed < 200
