"""The mixture guide: re-inferred with the wall, progress from the pose, a belief over the classes,
stiffness from the distribution's spread."""

import pytest
import torch

from protorch.control.teleop_guide import MixtureGuide, variance_map
from protorch.gp import make_env_map
from protorch.loop import demonstration_dataset
from protorch.primitives.promp import ProMP
from protorch.tasks import TeleopWindowTask
from protorch.tasks.teleop_operators import careful_demonstrations

TASK = TeleopWindowTask()
START, END = TASK.endpoint_poses()


@pytest.fixture(scope="module")
def guide():
    trajs, envs = careful_demonstrations(TASK, 6, 3, torch.Generator().manual_seed(0))
    promp = ProMP(7, 10, 100)
    ds = demonstration_dataset(
        promp, trajs, envs, labels=TASK.label(torch.stack(trajs), envs), var_floor=1e-6
    )
    factory = lambda: make_env_map("torch", alpha=3.0)  # noqa: E731
    env_map = factory().fit(ds.env, ds.mean, ds.var, ds.label)
    return MixtureGuide(promp, env_map, variance_map(factory, env_map), [0, 1], END[:3] - START[:3])


def _follow(guide, cls, env, steps=70):
    """A wish on class ``cls``'s mean at the wall ``env (1, 4)``, step by step: the executed poses,
    the beliefs and phases."""
    mu, _ = guide.infer(env)
    state, out = guide.start(1), []
    for t in range(steps):
        x, state, comp = guide.step(state, mu[:, cls, t], env, 0.02)
        out.append((x, state.belief[0].clone(), state.z[0].clone(), comp))
    return mu, out


def test_following_one_class_the_belief_goes_to_it_and_the_guide_leaves_the_mean_alone(guide):
    env = torch.tensor([[0.62, 0.05, 0.5, 0.3]], dtype=torch.float64)
    for cls in (0, 1):
        mu, out = _follow(guide, cls, env)
        assert float(out[-1][1][cls]) > 0.99
        z = torch.stack([o[2][cls] for o in out])
        assert bool((z[1:] >= z[:-1]).all())  # the phase never runs back
        # on the mean the pull is ~0: the executed pose is the wish (the other class weighs <= the
        # floor)
        gap = torch.stack([(o[0][0, :3] - mu[0, cls, t, :3]).norm() for t, o in enumerate(out)])
        assert float(gap[40:].max()) < 0.02


def test_the_guide_is_re_inferred_at_each_wall_pose(guide):
    envs = guide.env_map.E[guide.env_map.labels == 0]  # walls demonstrated in class 0
    mu, _ = guide.infer(envs)  # (G, 2, T, 7)
    assert (
        float(torch.cdist(envs[:, :3], envs[:, :3]).max()) > 0.1
    )  # walls far apart: no one path fits all
    for g in range(envs.shape[0]):
        d = torch.linalg.vector_norm(
            mu[g, 0, :, :3] - envs[g, :3], dim=-1
        )  # to this wall's window centre
        assert float(d.min()) < 0.03


def test_stiffness_follows_the_spread_firm_at_the_window_free_between(guide):
    env = torch.tensor([[0.6, 0.0, 0.5, 0.2]], dtype=torch.float64)
    mu, std = guide.infer(env)
    i = int(torch.linalg.vector_norm(mu[0, 0, :, :3] - env[0, :3], dim=-1).argmin())
    wide = int(std[0, 0, :, 1].argmax())
    assert float(std[0, 0, i, 1]) < float(std[0, 0, wide, 1])
    # a wish 5 cm off the mean, sideways: pulled back more where the distribution is narrow
    pulls = []
    for t in (i, wide):
        state = guide.start(1)
        state.z[:] = t
        state.belief[:] = torch.tensor([1.0, 0.0])
        wish = mu[:, 0, t].clone()
        wish[0, 1] += 0.05
        x, _, comp = guide.step(state, wish, env, 0.0)
        pulls.append((float(wish[0, 1] - x[0, 1]), float(comp)))
    assert pulls[0][0] > pulls[1][0] and pulls[0][1] < pulls[1][1]
