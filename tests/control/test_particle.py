"""The online test of Fig. 6 (protorch.control.particle) and its figures
(protorch.figures.online): the bounded random walk, the marker at the current phase, the PD
simulation against hand-computed steps, success / collision on straight paths, one map query per
control step, input checks."""

from __future__ import annotations

import math

import pytest
import torch

from protorch.control.particle import (
    EpisodeResult,
    basis_derivative_at,
    promp_state_at,
    random_walk_envs,
    run_episodes,
    walk_bounds,
)
from protorch.gp import make_env_map
from protorch.gp.model import EnvToProMP
from protorch.primitives.promp import ProMP
from protorch.tasks import PointParticleTask

F64 = torch.float64
TASK = PointParticleTask()

# start (1, 5), wall x in [4, 6], hole y in (4, 6) centred at (5, 5), goal (9, 5)
ENV = torch.tensor([1.0, 5.0, 5.0, 5.0, 9.0, 5.0], dtype=F64)


def promp() -> ProMP:
    return ProMP(2, 10, 100)


def line_weights(p: ProMP, start, goal) -> torch.Tensor:
    """ProMP weights ``(N,)`` of a straight line ``start -> goal`` with a minimum-jerk timing."""
    s = torch.linspace(0, 1, p.num_steps, dtype=F64)
    s = s**3 * (10 - 15 * s + 6 * s**2)  # (T,)
    start, goal = torch.as_tensor(start, dtype=F64), torch.as_tensor(goal, dtype=F64)
    return p.weights((start + s[:, None] * (goal - start))[None])[0]  # (N,)


class FixedModel:
    """A stand-in map: the same weight vector(s) whatever the environment; counts its calls."""

    def __init__(self, p: ProMP, w: torch.Tensor) -> None:
        self.promp, self.w, self.calls = p, w, []
        self.env_map = self

    def predict_mean(self, env: torch.Tensor) -> torch.Tensor:
        self.calls.append(env.clone())
        w = self.w if self.w.ndim == 2 else self.w.expand(env.shape[0], -1)
        return w.clone()


def static_walk(env: torch.Tensor, duration: float, dt: float) -> torch.Tensor:
    steps = int(math.ceil(duration / dt - 1e-9))
    return env.reshape(1, 1, -1).expand(1, steps + 1, -1).clone()


# ------------------------------------------------------------------ random walk
def test_random_walk_stays_in_bounds_and_keeps_start_and_wall(gen):
    env0 = TASK.sample_envs(50, gen)
    walk = random_walk_envs(
        TASK, env0, 500, step_std=0.5, generator=gen
    )  # big steps: many reflections
    assert walk.shape == (50, 501, 6)
    assert torch.equal(walk[:, 0], env0)
    lo, hi = walk_bounds(TASK, walk)  # (E, S+1, 3)
    moved = walk[..., 3:6]
    assert bool((moved >= lo - 1e-12).all()) and bool((moved <= hi + 1e-12).all())
    assert torch.equal(walk[..., :3], env0[:, None, :3].expand(-1, 501, -1))  # start, wall_x fixed
    assert float(moved.diff(dim=1).abs().amax()) > 0.5  # it did move


def test_random_walk_step_std_matches(gen):
    # environments in the middle of the ranges and small steps: reflections are rare
    env0 = torch.tensor([[1.0, 5.0, 3.0, 5.0, 7.25, 5.0]], dtype=F64).repeat(200, 1)
    stds = (0.01, 0.02, 0.005)
    walk = random_walk_envs(TASK, env0, 300, step_std=stds, generator=gen)
    d = walk[..., 3:6].diff(dim=1).reshape(-1, 3)  # (E * S, 3)
    for k, s in enumerate(stds):
        assert float(d[:, k].std()) == pytest.approx(s, rel=0.02)
        assert abs(float(d[:, k].mean())) < 4 * s / math.sqrt(d.shape[0])
    one = random_walk_envs(TASK, env0[:20], 100, step_std=0.03, generator=gen)
    assert float(one[..., 3:6].diff(dim=1).std()) == pytest.approx(0.03, rel=0.05)


def test_random_walk_zero_std_is_constant_and_4d_layout(gen):
    env0 = TASK.sample_envs(5, gen)
    walk = random_walk_envs(TASK, env0, 30, step_std=0.0, generator=gen)
    assert torch.equal(walk, env0[:, None].expand(-1, 31, -1))
    assert random_walk_envs(TASK, env0, 0, step_std=0.1).shape == (5, 1, 6)
    task4 = PointParticleTask(fixed_start=(0.0, 5.0))
    env4 = task4.sample_envs(10, gen)  # (wall_x, hole_y, goal_x, goal_y)
    walk4 = random_walk_envs(task4, env4, 200, step_std=0.3, generator=gen)
    assert torch.equal(walk4[..., 0], env4[:, None, 0].expand(-1, 201))  # wall_x fixed
    assert bool((walk4[..., 1:].diff(dim=1) != 0).all())
    lo, hi = walk_bounds(task4, walk4)
    assert bool((walk4[..., 1:] >= lo - 1e-12).all()) and bool((walk4[..., 1:] <= hi + 1e-12).all())


def test_random_walk_rejects_bad_inputs(gen):
    env0 = TASK.sample_envs(3, gen)
    with pytest.raises(ValueError, match="hole_y"):
        random_walk_envs(TASK, env0.clone().index_fill_(1, torch.tensor([3]), 9.5), 5, step_std=0.1)
    with pytest.raises(ValueError, match=r"\(E, 6\)"):
        random_walk_envs(TASK, env0[:, :4], 5, step_std=0.1)
    with pytest.raises(ValueError, match="step_std"):
        random_walk_envs(TASK, env0, 5, step_std=-0.1)
    with pytest.raises(ValueError, match="num_steps"):
        random_walk_envs(TASK, env0, -1, step_std=0.1)


# ------------------------------------------------------------------ the marker
def test_marker_equals_trajectory_on_the_phase_grid_and_derivative_is_exact(gen):
    p = promp()
    w = 3 * torch.randn(4, p.num_weights, generator=gen, dtype=F64)  # (4, N)
    traj = p.trajectory(w)  # (4, T, 2)
    for k in range(p.num_steps):
        pos, _ = promp_state_at(p, w, float(p.phase[k]))
        torch.testing.assert_close(pos, traj[:, k], rtol=0, atol=1e-10)
    h = 1e-6
    for z in (0.0, 0.13, 0.5, 0.97, 1.0):
        fd = (p.basis_at([z + h]) - p.basis_at([z - h])) / (2 * h)  # (1, K)
        torch.testing.assert_close(basis_derivative_at(p, z), fd, rtol=1e-6, atol=1e-8)
        _, dpos = promp_state_at(p, w, z)
        fd_pos = (promp_state_at(p, w, z + h)[0] - promp_state_at(p, w, z - h)[0]) / (2 * h)
        torch.testing.assert_close(dpos, fd_pos, rtol=1e-6, atol=1e-6)


def test_run_episodes_markers_follow_the_mean_in_phase():
    p = promp()
    w = line_weights(p, (1.0, 5.0), (9.0, 5.0))
    # duration 0.99 s at dt 0.01: control phase t / 99 is exactly the ProMP's grid phase t
    res = run_episodes(
        FixedModel(p, w), TASK, walk=static_walk(ENV, 0.99, 0.01), duration=0.99, hold=0.0
    )
    torch.testing.assert_close(res.markers[0], p.trajectory(w), rtol=0, atol=1e-10)


def test_marker_is_retimed_from_the_current_phase():
    """When the environment (hence the map's answer) changes, the marker jumps to the new mean at
    the current phase, not to the new mean's start."""
    p = promp()
    w_low = line_weights(p, (1.0, 5.0), (9.0, 3.0))
    w_high = line_weights(p, (1.0, 5.0), (9.0, 7.0))

    class Switch(FixedModel):
        def predict_mean(self, env):
            self.calls.append(env.clone())
            return torch.where(env[:, 3:4] < 5.5, w_low, w_high)  # by hole_y

    walk = static_walk(ENV, 2.0, 0.01)
    walk[:, 120:, 3] = 6.0  # the hole jumps up at t = 1.2 s
    res = run_episodes(Switch(p, w_low), TASK, walk=walk, duration=2.0, hold=0.0)
    for t, w in ((119, w_low), (120, w_high), (150, w_high)):
        z = t * 0.01 / 2.0
        torch.testing.assert_close(
            res.markers[0, t], p.trajectory(w, phase=[z])[0], rtol=0, atol=1e-10
        )
    assert float((res.markers[0, 120] - res.markers[0, 119]).norm()) > 0.5  # a jump, mid-path


# ------------------------------------------------------------------ the PD simulation
def test_first_steps_are_semi_implicit_euler_pd():
    p = promp()
    w = line_weights(p, (2.0, 5.0), (9.0, 5.0))  # starts 1 to the right of the env's start
    kp, kd, dt, dur = 1000.0, 30.0, 0.01, 2.0
    res = run_episodes(
        FixedModel(p, w),
        TASK,
        walk=static_walk(ENV, dur, dt),
        duration=dur,
        dt=dt,
        kp=kp,
        kd=kd,
        mass=2.0,
    )
    x, v = ENV[:2].clone(), torch.zeros(2, dtype=F64)
    torch.testing.assert_close(res.positions[0, 0], x)
    for t in range(3):
        m, dm = promp_state_at(p, w, t * dt / dur)
        acc = (kp * (m - x) + kd * (dm / dur - v)) / 2.0
        v = v + acc * dt
        x = x + v * dt
        torch.testing.assert_close(res.positions[0, t + 1], x, rtol=0, atol=1e-12)
        torch.testing.assert_close(res.velocities[0, t + 1], v, rtol=0, atol=1e-12)


def test_pd_tracks_a_straight_path_through_the_hole():
    p = promp()
    w = line_weights(p, (1.0, 5.0), (9.0, 5.0))
    res = run_episodes(FixedModel(p, w), TASK, walk=static_walk(ENV, 2.0, 0.01))
    err = (res.positions[0] - res.markers[0]).norm(dim=-1)  # (T+1,)
    assert float(err.amax()) < 0.02  # velocity feed-forward: no lag
    assert float(err[-1]) < 1e-3  # at rest on the marker's end after the 0.5 s hold
    assert float((res.positions[0, -1] - p.trajectory(w)[-1]).norm()) < 1e-3
    assert bool(res.success[0]) and not bool(res.collided[0])
    assert float(res.final_goal_distance[0]) < 0.01
    assert res.success_rate == 1.0
    assert res.num_steps == 250 and res.num_moving_steps == 200 and res.hold == pytest.approx(0.5)


def test_straight_path_through_the_wall_collides():
    p = promp()
    env = torch.tensor(
        [1.0, 1.0, 5.0, 7.0, 9.0, 1.0], dtype=F64
    )  # hole at y in (6, 8), path at y = 1
    w = line_weights(p, (1.0, 1.0), (9.0, 1.0))
    res = run_episodes(FixedModel(p, w), TASK, walk=static_walk(env, 2.0, 0.01))
    assert bool(res.collided[0]) and not bool(res.success[0])
    assert float(res.final_goal_distance[0]) < 0.01  # it failed by the wall alone


def test_collision_uses_the_moving_hole():
    """A path that is clear of the wall in the first environment but not after the hole moved."""
    p = promp()
    w = line_weights(p, (1.0, 5.0), (9.0, 5.0))
    walk = static_walk(ENV, 2.0, 0.01)
    walk[:, 80:, 3] = 7.5  # hole now (6.5, 8.5): the line y = 5 crosses the lower rectangle
    res = run_episodes(FixedModel(p, w), TASK, walk=walk)
    assert TASK.collides(res.positions[0], ENV).item() is False
    assert bool(res.collided[0]) and not bool(res.success[0])


@pytest.mark.slow
def test_real_gp_map_on_straight_lines_succeeds_at_known_envs():
    p = promp()
    envs, ws = [], []
    for hy in (3.0, 5.0, 7.0):
        for gy in (hy - 0.5, hy + 0.5):
            e = torch.tensor([1.0, hy, 5.0, hy, 9.0, gy], dtype=F64)
            envs.append(e)
            ws.append(line_weights(p, e[:2], e[4:]))
    E, W = torch.stack(envs), torch.stack(ws)  # (6, 6), (6, N)
    env_map = make_env_map("torch", 1e-3).fit(E, W, torch.full_like(W, 1e-6))
    model = EnvToProMP(p, env_map, "point_particle")
    res = run_episodes(model, TASK, E, step_std=0.0)
    assert bool(res.success.all()), res.summary()
    assert float(res.final_goal_distance.amax()) < 0.02


def test_start_choice():
    p = promp()
    w = line_weights(p, (2.0, 5.0), (9.0, 5.0))
    walk = static_walk(ENV, 1.0, 0.01)
    at_env = run_episodes(FixedModel(p, w), TASK, walk=walk, duration=1.0)
    at_marker = run_episodes(FixedModel(p, w), TASK, walk=walk, duration=1.0, start="marker")
    torch.testing.assert_close(at_env.positions[0, 0], ENV[:2])
    torch.testing.assert_close(at_marker.positions[0, 0], at_marker.markers[0, 0])


# ------------------------------------------------------------------ the map's queries
def test_map_is_queried_once_per_step_with_all_episodes(gen):
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    env0 = TASK.sample_envs(7, gen)
    res = run_episodes(model, TASK, env0, duration=0.5, hold=0.1, generator=gen)
    assert len(model.calls) == res.num_steps + 1 == 61  # one per instant t = 0..T
    for t, env in enumerate(model.calls):
        assert env.shape == (7, 6)
        assert torch.equal(env, res.envs[:, t])  # the current environments, all episodes at once
    assert bool((res.envs[:, 50, 3:] != res.envs[:, 0, 3:]).any())  # they moved
    assert torch.equal(
        res.envs[:, 50:], res.envs[:, 50:51].expand(-1, 11, -1)
    )  # frozen for the hold


def test_bare_callable_model_and_record_false(gen):
    p = promp()
    w = line_weights(p, (1.0, 5.0), (9.0, 5.0))
    calls = []

    def model(env):
        calls.append(env.shape[0])
        return w.expand(env.shape[0], -1), torch.zeros(env.shape[0], p.num_weights, dtype=F64)

    with pytest.raises(ValueError, match="promp"):
        run_episodes(model, TASK, ENV[None])
    res = run_episodes(model, TASK, ENV[None], promp=p, step_std=0.0, record=False)
    assert res.markers is None and res.weights is None and bool(res.success[0])
    assert calls == [1] * (res.num_steps + 1)
    with pytest.raises(ValueError, match="record=False"):
        res.episode(0)


def test_same_seed_same_result(gen):
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    env0 = TASK.sample_envs(4, gen)
    a = run_episodes(model, TASK, env0, duration=0.5, generator=torch.Generator().manual_seed(3))
    b = run_episodes(model, TASK, env0, duration=0.5, generator=torch.Generator().manual_seed(3))
    assert torch.equal(a.positions, b.positions) and torch.equal(a.envs, b.envs)


# ------------------------------------------------------------------ input checks
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": -0.01}, "dt"),
        ({"duration": 0.0}, "duration"),
        ({"duration": float("nan")}, "duration"),
        ({"kp": 0.0}, "kp"),
        ({"kd": -1.0}, "kd"),
        ({"mass": 0.0}, "mass"),
        ({"hold": -0.1}, "hold"),
        ({"goal_tol": -0.2}, "goal_tol"),
        ({"start": "middle"}, "start"),
        ({"dt": 0.5, "duration": 0.2}, "dt"),
        ({"step_std": -1.0}, "step_std"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    with pytest.raises(ValueError, match=match):
        run_episodes(model, TASK, ENV[None], **kwargs)
    assert model.calls == []  # checked before any work


def test_bad_environments_raise():
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    with pytest.raises(ValueError, match=r"\(E, 6\)"):
        run_episodes(model, TASK, ENV[None, :4])
    with pytest.raises(ValueError, match="NaN"):
        run_episodes(model, TASK, ENV.clone().fill_(float("nan"))[None])
    with pytest.raises(ValueError, match="dimensions"):
        run_episodes(model, TASK, ENV)
    with pytest.raises(ValueError, match="env0 .*or walk"):
        run_episodes(model, TASK)
    with pytest.raises(ValueError, match="not both"):
        run_episodes(model, TASK, ENV[None], walk=static_walk(ENV, 2.0, 0.01))
    with pytest.raises(ValueError, match=r"walk must be \(E, 201, 6\)"):
        run_episodes(model, TASK, walk=static_walk(ENV, 1.0, 0.01))
    with pytest.raises(ValueError, match="2 DoF"):
        run_episodes(FixedModel(ProMP(3, 5), torch.zeros(15, dtype=F64)), TASK, ENV[None])
    with pytest.raises(ValueError, match="model"):
        run_episodes(object(), TASK, ENV[None], promp=p)
    assert model.calls == []

    bad = FixedModel(p, torch.zeros(p.num_weights + 1, dtype=F64))
    with pytest.raises(ValueError, match="mean weights of shape"):
        run_episodes(bad, TASK, ENV[None])


# ------------------------------------------------------------------ figures
def _result() -> EpisodeResult:
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    return run_episodes(
        model,
        TASK,
        ENV[None].repeat(2, 1),
        duration=0.5,
        hold=0.1,
        generator=torch.Generator().manual_seed(0),
    )


def test_frames_png_and_gif(tmp_path):
    from PIL import Image

    from protorch.figures.online import plot_episode_frames, write_episode_gif

    ep = _result().episode(1)
    assert ep["positions"].shape == (61, 2) and ep["envs"].shape == (61, 6)
    assert ep["means"].shape == (61, 100, 2) and ep["markers"].shape == (61, 2)
    png = plot_episode_frames(tmp_path / "sub" / "frames.png", **ep, num_frames=4, title="test")
    assert png == tmp_path / "sub" / "frames.png"
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size[0] > 3 * im.size[1]  # a row of 4 frames
    gif = write_episode_gif(tmp_path / "episode.gif", **ep, max_frames=5)
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 5
    assert sorted(f.name for f in tmp_path.iterdir()) == [
        "episode.gif",
        "sub",
    ]  # no temp files left
    assert [f.name for f in (tmp_path / "sub").iterdir()] == ["frames.png"]


def test_frame_inputs_are_checked(tmp_path):
    from protorch.figures.online import plot_episode_frames

    ep = _result().episode(0)
    with pytest.raises(ValueError, match="envs"):
        plot_episode_frames(tmp_path / "x.png", **{**ep, "envs": ep["envs"][:, :4]})
    with pytest.raises(ValueError, match="frames"):
        plot_episode_frames(tmp_path / "x.png", **ep, frames=[0, 999])
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ unstable or oversized settings
@pytest.mark.parametrize(
    "kwargs, match",
    [
        # kp dt^2 = 10: the explicit PD step diverges (a goal distance of ~1e25 if it ran)
        (
            {"dt": 0.1, "kp": 1000.0},
            r"dt = 0\.1 with kp = 1000.*kp dt\^2 / mass \+ 2 kd dt / mass < 4, got 16",
        ),
        ({"kp": 1e6}, r"dt = 0\.01 with kp = 1e\+06.*< 4, got 100\.6"),  # NaN positions if it ran
        ({"kd": 300.0, "mass": 1.0}, r"kd = 300.*< 4, got 6\.1"),  # the damping alone overshoots
        ({"dt": 1e-6}, r"2500000 control steps per episode, over the limit of 1000000"),
        ({"duration": 20000.0}, r"control steps per episode, over the limit of 1000000"),
    ],
)
def test_unstable_or_huge_settings_are_refused_before_any_work(kwargs, match):
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    with pytest.raises(ValueError, match=match):
        run_episodes(model, TASK, ENV[None], **kwargs)
    assert model.calls == []


def test_gains_just_inside_the_bound_stay_bounded():
    # kp dt^2 + 2 kd dt = 3.9 at dt = 0.05 (kp = 1000, kd = 14): stable, if badly damped
    p = promp()
    model = FixedModel(p, line_weights(p, (1.0, 5.0), (9.0, 5.0)))
    res = run_episodes(
        model, TASK, walk=static_walk(ENV, 2.0, 0.05), dt=0.05, kp=1000.0, kd=14.0, hold=5.0
    )
    assert bool(torch.isfinite(res.positions).all())
    assert float(res.final_goal_distance[0]) < 0.2
