"""Multimodality on the arm task: label-aware inference never averages a left and a right
solution through the can (labels off does), and the online episode (protorch.control.arm)
switches sides on the fly when the can is moved, within the joint velocity and acceleration
limits."""

from __future__ import annotations

import pytest
import torch

from protorch import ProMP
from protorch.control.arm import count_switches, run_arm_episodes
from protorch.gp import make_env_map
from protorch.gp.model import EnvToProMP, label_aware_mean
from protorch.loop import demonstration_dataset
from protorch.tasks.arm.reach import LEFT, RIGHT, ArmReachTask

F64 = torch.float64
pytestmark = pytest.mark.slow  # IK demonstrations and an arm map built per module: ~15 s of CPU


@pytest.fixture(scope="module")
def task():
    return ArmReachTask()


def both_sides(task, envs, seed=0, **kw):
    """A data set with a left and a right entry (2 IK demonstrations each) per environment."""
    g = torch.Generator().manual_seed(seed)
    n = envs.shape[0]
    dl, el, ll = task.demonstrations(
        envs, 2, g, sides=torch.full((n,), LEFT), lengths=(30, 30), **kw
    )
    dr, er, lr = task.demonstrations(
        envs, 2, g, sides=torch.full((n,), RIGHT), lengths=(30, 30), **kw
    )
    promp = ProMP(task.num_dof, 10, 50)
    labels = torch.cat([ll, lr])
    assert labels.tolist() == [LEFT] * 2 * n + [RIGHT] * 2 * n
    return promp, demonstration_dataset(
        promp, dl + dr, torch.cat([el, er]), labels=labels, var_floor=1e-3
    )


def test_left_and_right_data_never_average_through_the_can(task):
    # the can on the straight start-target line (y = 0); mirror-image demonstrations on both sides
    envs = torch.tensor(
        [[0.53, 0.0, 0.70, 0.0], [0.56, 0.0, 0.74, 0.0], [0.59, 0.0, 0.72, 0.0]], dtype=F64
    )
    promp, ds = both_sides(task, envs, pass_distance=(0.2, 0.2), goal_noise=0.0, tremor=0.0)
    between = torch.tensor([[0.545, 0.0, 0.72, 0.0], [0.575, 0.0, 0.73, 0.0]], dtype=F64)
    query = torch.cat([envs, between])  # the data and between it
    var = torch.full_like(ds.var, 1e-3)  # left and right equally confident
    on = make_env_map("torch", 30.0).fit(ds.env, ds.mean, var, ds.label)
    off = make_env_map("torch", 30.0).fit(ds.env, ds.mean, var)  # the same data, labels dropped
    best = label_aware_mean(on, promp, task, query, dtype=F64)
    clear = task.can_radius + task.margin
    d_on = task.can_distance(promp.trajectory(best.mean), query)
    d_off = task.can_distance(promp.trajectory(off.predict_mean(query)), query)
    assert bool((d_on > clear).all()), d_on  # a whole detour, on one side
    assert bool((d_off < task.can_radius).all()), d_off  # the average of both: through the can
    # each class alone also stays on its side
    for k in (LEFT, RIGHT):
        traj = promp.trajectory(on.predict_mean(query, k))
        assert task.side(traj, query).tolist() == [k] * query.shape[0]


@pytest.fixture(scope="module")
def switching(task):
    """A map learned from both sides of the can at A (can left of the line) and B (right of it)."""
    a = torch.tensor([0.56, 0.05, 0.72, 0.0], dtype=F64)
    b = torch.tensor([0.56, -0.05, 0.72, 0.0], dtype=F64)
    promp, ds = both_sides(task, torch.stack([a, b]), seed=1)
    model = EnvToProMP(promp, make_env_map("torch", 30.0).fit(ds.env, ds.mean, ds.var, ds.label))
    walk = a.repeat(1, 101, 1)  # 2 s at dt 0.02: 100 moving steps
    walk[:, 25:] = b  # a person moves the can across the line at a quarter of the motion
    return model, walk


def test_the_arm_switches_sides_when_the_can_is_moved(task, switching):
    model, walk = switching
    res = run_arm_episodes(model, task, walk=walk, duration=2.0, hold=0.5, dt=0.02)
    lab = res.labels[0]
    assert (
        int(lab[0]) == RIGHT and int(lab[-1]) == LEFT
    )  # the short way round, before and after the move
    assert int(res.switches[0]) == 1 and int(count_switches(res.labels)[0]) == 1
    assert bool(res.success[0]) and float(res.min_can_distance[0]) > task.can_radius + task.margin
    assert float(res.final_goal_distance[0]) <= task.goal_tol
    # velocity and acceleration limits held at every step
    vmax, amax = task.kinematics.max_velocity, torch.tensor(task.robot.max_acceleration, dtype=F64)
    assert bool((res.qd.abs() <= vmax + 1e-9).all())
    assert bool((res.qd.diff(dim=1).abs() / res.dt <= amax + 1e-6).all())
    assert (
        res.map_queries == 2 * 2
    )  # both classes at A, then at B: unchanged environments reuse the answer
    again = run_arm_episodes(
        model, task, walk=walk, duration=2.0, hold=0.5, dt=0.02, reuse_answers=False
    )
    assert (
        torch.allclose(again.q, res.q) and again.map_queries == 2 * 126
    )  # asked afresh every step
    ep = res.episode(0)
    assert (
        ep["links"].shape == (126, 11, 3)
        and ep["means"].shape[-1] == 3
        and ep["labels"].shape == (126,)
    )


def test_without_labels_there_is_nothing_to_switch_to(task, switching):
    model, walk = switching
    em = model.env_map
    off = EnvToProMP(model.promp, make_env_map("torch", 30.0).fit(em.E, em.MU, em.VAR))
    res = run_arm_episodes(off, task, walk=walk, duration=2.0, hold=0.5, dt=0.02)
    assert int(res.switches[0]) == 0 and bool((res.labels == 0).all())


def test_random_moves_never_put_the_can_onto_the_arm(task, switching, gen):
    model, _ = switching
    env0 = task.sample_envs(6, gen)
    res = run_arm_episodes(
        model, task, env0, duration=2.0, hold=0.2, dt=0.05, moves=(2,), generator=gen
    )
    changed = (res.envs[:, 1:] != res.envs[:, :-1]).any(-1)  # (E, T)
    assert (
        changed.sum(-1).tolist() == res.moves.tolist() and int(res.moves.sum()) >= 10
    )  # two each, but a
    # move is skipped when both fall on the same step or no place is clear of the arm
    for e, t in torch.nonzero(
        changed
    ).tolist():  # the instant after each move: can clear of the arm
        links = task.kinematics.link_positions(res.q[e, t + 1])
        d = task.skeleton_distance(links[None], res.envs[e, t + 1])
        assert float(d) > task.can_radius + 0.05
    assert bool(task.valid_envs(res.envs).all())
    s = res.summary()
    assert (
        s["episodes"] == 6
        and s["moves"] == int(res.moves.sum())
        and 0.0 <= s["success_rate"] <= 1.0
    )


def test_bad_input_is_refused(task, switching):
    model, walk = switching
    with pytest.raises(ValueError, match="env_map"):
        run_arm_episodes(object(), task, walk=walk)
    with pytest.raises(ValueError, match=r"walk must be \(E, 101, 4\)"):
        run_arm_episodes(model, task, walk=walk[:, :50], duration=2.0, dt=0.02)
    with pytest.raises(ValueError, match="off the table"):
        run_arm_episodes(model, task, torch.tensor([[0.55, 0.0, 1.5, 0.0]], dtype=F64))
    with pytest.raises(ValueError, match="give env0 or walk"):
        run_arm_episodes(model, task, walk[:, 0], walk=walk)
    with pytest.raises(ValueError, match="move_window"):
        run_arm_episodes(model, task, walk[:, 0], move_window=(0.5, 0.2))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (
            {"kp": 100.0},
            r"dt = 0\.02 with kp = 100.*kp dt < 2, got 2",
        ),  # the unclamped loop: e *= (1 - kp dt) = -1
        ({"dt": 0.5, "duration": 3.0}, r"dt = 0\.5 with kp = 10.*kp dt < 2, got 5"),
        ({"dt": 1e-6}, r"4000000 control steps per episode, over the limit of 1000000"),
    ],
)
def test_unstable_or_huge_settings_are_refused(task, switching, kwargs, match):
    model, walk = switching
    with pytest.raises(ValueError, match=match):
        run_arm_episodes(model, task, walk[:, 0], **kwargs)


def test_a_six_joint_arm_moves_within_its_own_limits(tmp_path):
    """The moving test reads the task's robot (a 6-joint arm once crashed on the
    Panda's 7 limits)."""
    from tests.robots.user_arm import user_arm_home, write_user_arm

    six = ArmReachTask(
        robot={
            "urdf": str(write_user_arm(tmp_path)),
            "end_link": "tool0",
            "home": user_arm_home(),
            "max_acceleration": 4.0,
        },
        # the Panda's workspace, which this arm reaches (auto would measure the arm's own)
        can_box=((0.50, 0.62), (-0.12, 0.12)),
        goal_box=((0.66, 0.74), (-0.24, 0.24)),
        table=((0.2, 0.9), (-0.5, 0.5)),
        can_radius=0.0375,
        can_height=0.23,
    )
    a = torch.tensor([0.56, 0.05, 0.72, 0.0], dtype=F64)
    promp, ds = both_sides(six, a[None], seed=1)
    model = EnvToProMP(promp, make_env_map("torch", 30.0).fit(ds.env, ds.mean, ds.var, ds.label))
    res = run_arm_episodes(model, six, walk=a.repeat(1, 51, 1), duration=1.0, hold=0.2, dt=0.02)
    assert res.q.shape[-1] == 6
    assert bool((res.qd.abs() <= six.kinematics.max_velocity + 1e-9).all())
    assert bool((res.qd.diff(dim=1).abs() / res.dt <= 4.0 + 1e-6).all())  # robot.max_acceleration
    assert (
        float((res.qd.diff(dim=1).abs() / res.dt).max()) > 3.0
    )  # the limit is reached, so it binds
