"""The authors' moving test (protorch.control.paper_scenario): the walk against a step-by-step
scalar transcription of main3.py's ``change_env``, its ranges and speeds, the first
environments, and the episodes it feeds to ``run_episodes``."""

from __future__ import annotations

import pytest
import torch

from protorch.control.paper_scenario import (
    PAPER_START,
    paper_walk,
    run_paper_episodes,
    sample_paper_envs,
)
from protorch.control.particle import run_episodes
from protorch.primitives.promp import ProMP
from protorch.tasks import PointParticleTask

F64 = torch.float64
TASK = PointParticleTask()


def change_env_scalar(env, d):
    """main3.py's change_env on one 6-D environment (plain floats); ``d = [dwx, dwy, dey]``."""
    wx, wy, ex, ey = env[2], env[3], env[4], env[5]
    dwx, dwy, dey = d
    wx += dwx
    ex += dwx
    if ex < wx + 1.5 or ex > 10:
        ex -= dwx
    if wx < 2 or wx > 8:
        wx -= dwx
        dwx = -dwx
    wy += dwy
    if wy < 1 or wy > 9:
        wy -= dwy
        dwy = -dwy
    ey += dey
    if ey < 0 or ey > 10:
        ey -= dey
        dey = -dey
    return [0.0, 5.0, wx, wy, ex, ey], [dwx, dwy, dey]


def test_walk_is_the_authors_change_env_step_by_step():
    env0 = sample_paper_envs(TASK, 6, torch.Generator().manual_seed(1))  # (6, 6)
    walk = paper_walk(TASK, env0, 200)  # (6, 201, 6)
    assert walk.shape == (6, 201, 6)
    for e in range(6):
        env, d = env0[e].tolist(), [0.1, 0.1, 0.1]
        for t in range(200):
            env, d = change_env_scalar(env, d)
            assert walk[e, t].tolist() == pytest.approx(env, abs=1e-12)
        assert walk[e, 200].tolist() == walk[e, 199].tolist()  # frozen after the moving steps


def test_walk_ranges_speed_and_fixed_start():
    env0 = sample_paper_envs(TASK, 50, torch.Generator().manual_seed(2))
    walk = paper_walk(TASK, env0, 200)  # (50, 201, 6)
    assert bool((walk[..., 0] == PAPER_START[0]).all()) and bool(
        (walk[..., 1] == PAPER_START[1]).all()
    )
    wx, wy, gx, gy = walk[..., 2], walk[..., 3], walk[..., 4], walk[..., 5]
    assert float(wx.min()) >= 2 - 1e-9 and float(wx.max()) <= 8 + 1e-9
    assert float(wy.min()) >= 1 - 1e-9 and float(wy.max()) <= 9 + 1e-9
    assert (
        float(gy.min()) >= -1e-9 and float(gy.max()) <= 10 + 1e-9 and float(gx.max()) <= 10 + 1e-9
    )
    # the hole's y and the goal's y move 0.1 every step, or 0 when a step is undone at a bound
    for x in (wy, gy):
        step = x[:, 1:200].diff(dim=1).abs()  # (50, 198)
        assert bool(((step - 0.1).abs() < 1e-9).logical_or(step < 1e-9).all())
        assert float((step > 0.05).double().mean()) > 0.9
    # the wall really travels: over 2 s it covers several units in x
    assert float((wx.amax(1) - wx.amin(1)).min()) > 3.0


def test_first_environments_and_the_4d_layout():
    env0 = sample_paper_envs(TASK, 500, torch.Generator().manual_seed(3))
    assert env0.shape == (500, 6)
    assert bool((env0[:, 4] >= env0[:, 2] + 1.5).all()) and bool((env0[:, 4] <= 10).all())
    assert 2 <= float(env0[:, 2].min()) and float(env0[:, 2].max()) <= 8
    task4 = PointParticleTask(fixed_start=(0.0, 5.0))
    e4 = sample_paper_envs(task4, 5, torch.Generator().manual_seed(3))
    assert e4.shape == (5, 4)
    assert torch.allclose(e4, env0[:5, 2:])  # same draws, without the start
    w4 = paper_walk(task4, e4, 10)
    assert torch.allclose(w4, paper_walk(TASK, env0[:5], 10)[..., 2:])
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        paper_walk(task4, env0[:5], 10)


class StraightModel:
    """A stand-in map: the straight line start -> goal of each queried environment."""

    def __init__(self) -> None:
        self.promp = ProMP(2, 10, 100)
        self.env_map = self

    def predict_mean(self, env):
        s = torch.linspace(0, 1, self.promp.num_steps, dtype=F64)[None, :, None]  # (1, T, 1)
        start, goal = env[:, None, 0:2], env[:, None, 4:6]  # (E, 1, 2)
        return self.promp.weights(start + s * (goal - start))  # (E, N)


@pytest.mark.slow
def test_episodes_run_the_walk_through_run_episodes():
    model = StraightModel()
    env0 = sample_paper_envs(TASK, 4, torch.Generator().manual_seed(4))
    res = run_paper_episodes(model, TASK, env0)
    ref = run_episodes(model, TASK, walk=paper_walk(TASK, env0, 200))
    assert torch.equal(res.positions, ref.positions) and torch.equal(res.success, ref.success)
    assert torch.equal(res.envs[:, :201], paper_walk(TASK, env0, 200))
    assert bool((res.positions[:, 0] == torch.tensor(PAPER_START, dtype=F64)).all())
    frozen = run_paper_episodes(model, TASK, env0, step=0.0)
    assert bool((frozen.envs == env0[:, None]).all())
    with pytest.raises(ValueError, match="walk"):
        run_paper_episodes(model, TASK, env0, walk=ref.envs)
