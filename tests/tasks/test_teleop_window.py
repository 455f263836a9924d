"""The moving-wall beam task, its operators (plug-ins) and the trial simulation."""

import math

import pytest
import torch

from protorch.primitives.pose import quaternion_distance
from protorch.tasks import TeleopWindowTask
from protorch.tasks.teleop_operators import (
    ScreenOperator,
    VariedOperator,
    careful_demonstrations,
    load_operator,
    probe_operator,
)
from protorch.tasks.teleop_trials import draw_schedules, run_trials

TASK = TeleopWindowTask()
START, END = TASK.endpoint_poses()


def _demos(n_envs=4, per_env=2, seed=0):
    trajs, envs = careful_demonstrations(TASK, n_envs, per_env, torch.Generator().manual_seed(seed))
    return torch.stack(trajs), envs


def test_careful_demonstrations_pass_and_carry_the_class_they_were_made_in():
    trajs, envs = _demos()
    assert bool(TASK.success(trajs, envs).all())
    assert TASK.label(trajs, envs).tolist() == [
        0,
        0,
        1,
        1,
        0,
        0,
        1,
        1,
    ]  # classes alternate between walls
    moved = envs.clone()
    moved[:, 1] += 0.15  # the same paths with the wall slid 15 cm along y: the upright beam hits it
    assert bool(TASK.collides(trajs, moved).all())
    cost = TASK.costs(trajs, envs)
    assert cost.shape == (8, 8) and bool((cost >= 0).all())


def test_the_two_classes_stand_the_beam_upright_rolled_opposite_ways():
    env = torch.tensor([[0.6, 0.0, 0.5, 0.3]], dtype=torch.float64)
    q = TASK.passing_quaternions(env)[0]  # (2, 4)
    assert float(quaternion_distance(q[0], q[1])) == pytest.approx(
        math.pi, abs=1e-9
    )  # a half turn apart
    centre = env[0, :3]
    for k in (0, 1):
        assert not bool(TASK.collides_at(torch.cat([centre, q[k]]), env[0]))
    assert bool(
        TASK.collides_at(torch.cat([centre, START[3:]]), env[0])
    )  # lying flat: it hits the wall


def test_wall_schedules_start_where_drawn_move_and_stay_in_range():
    walls = draw_schedules(TASK, 20, seed=3)
    assert torch.equal(walls.at(0.0), walls.env0)
    late = walls.at(100.0)
    assert bool((late != walls.env0).any(-1).all())  # every wall moved
    lo, hi = (
        torch.tensor(TASK.env_low, dtype=torch.float64),
        torch.tensor(TASK.env_high, dtype=torch.float64),
    )
    assert bool(((late >= lo - 1e-12) & (late <= hi + 1e-12)).all())
    assert torch.equal(draw_schedules(TASK, 20, seed=3).delta, walls.delta)  # the seed fixes them


def test_without_a_guide_the_beam_follows_the_wish():
    walls = draw_schedules(TASK, 3, seed=0, moves=0)
    ops = [ScreenOperator(i) for i in range(3)]
    r = run_trials(TASK, ops, walls, "none", dt=0.05, time_limit=6.0, record=True)
    for i in range(3):  # until it arrives (then the beam rests)
        k = int(round(float(r["time"][i]) / 0.05))
        assert torch.equal(r["poses"][i, :k], r["wishes"][i, :k])
    assert torch.equal(r["effort"], torch.zeros(3, dtype=torch.float64))
    assert bool((r["freedom"] == 1).all()) and bool(r["arrived"].all())
    assert torch.equal(r["success"], r["arrived"] & ~r["collided"])
    with pytest.raises(ValueError, match="unknown condition 'sometimes'"):
        run_trials(TASK, ops, walls, "sometimes")


PLUGIN = '''
import torch


class Straight:
    """Drives the beam along the line from start to end, rolled upright the first way."""

    def __init__(self, seed):
        self.seed = seed

    def reset(self, start, end, wall):
        self.start, self.end = start, end

    def act(self, t, pose, wall):
        s = min(t / 3.0, 1.0)
        return self.start + s * (self.end - self.start)


class NoAct:
    def __init__(self, seed):
        pass

    def reset(self, start, end, wall):
        pass


class Broken(Straight):
    def act(self, t, pose, wall):
        return torch.full((7,), float("nan"))
'''


def test_a_plugin_operator_from_a_file_outside_the_package_runs(tmp_path):
    path = tmp_path / "my_ops.py"
    path.write_text(PLUGIN)
    cls = load_operator(f"{path}:Straight")
    probe_operator(cls, TASK, START, END, draw_schedules(TASK, 1, 0).env0[0])
    r = run_trials(
        TASK,
        [cls(i) for i in range(2)],
        draw_schedules(TASK, 2, seed=1),
        "none",
        dt=0.1,
        time_limit=4.0,
    )
    assert bool(r["arrived"].all()) and bool(
        r["collided"].all()
    )  # straight through a wall: it arrives, touching
    with pytest.raises(ValueError, match="class NoAct lacks act"):
        load_operator(f"{path}:NoAct")
    with pytest.raises(ValueError, match=r"Broken.act returned a non-finite pose"):
        probe_operator(
            load_operator(f"{path}:Broken"), TASK, START, END, draw_schedules(TASK, 1, 0).env0[0]
        )
    with pytest.raises(ValueError, match="no file"):
        load_operator(f"{tmp_path / 'missing.py'}:Straight")
    assert load_operator("varied") is VariedOperator
    assert load_operator("protorch.tasks.teleop_operators.ScreenOperator") is ScreenOperator


def test_the_varied_population_differs_between_seeds_and_repeats_with_one():
    traits = [
        (op.duration, op.lag, op.tilt_std, op.cls_p) for op in (VariedOperator(i) for i in range(6))
    ]
    assert len(set(traits)) == 6
    a, b = VariedOperator(4), VariedOperator(4)
    wall = draw_schedules(TASK, 1, 0).env0[0]
    for op in (a, b):
        op.reset(START, END, wall)
    assert torch.equal(a.act(1.0, START, wall), b.act(1.0, START, wall))
