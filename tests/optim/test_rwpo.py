"""RWPO: the sigmoid relevance features, the learned relevance profile and its PRO updates."""

import math

import pytest
import torch

from protorch import RWPO, pro_update
from protorch.optim import rwpo_relevance_basis

F64 = torch.float64
TINY = {"relevance_iters": 3, "theta_samples": 8, "trajectory_samples": 4}


def early_late(w):
    """Objective 0 depends on the first three weights only, objective 1 on the last three."""
    return torch.stack([10.0 + w[..., :3].sum(-1), 10.0 + w[..., -3:].sum(-1)], -1)


def learn(mean, var=1.0, *, fn=early_late, **kw):
    """Run the relevance learning (iteration 0's asks) and return the optimiser."""
    kw = {
        "beta": 1.0,
        "num_objectives": 2,
        "num_samples": 10,
        "max_iter": 1,
        "tol": 0.0,
        "seed": 0,
        **TINY,
        **kw,
    }
    opt = RWPO(mean, var, **kw)
    opt.minimize(fn)
    return opt


# --------------------------------------------------------------------------- features
@pytest.mark.parametrize("k", [3, 10, 15])
def test_features_match_the_guide_formula(k):
    feats = rwpo_relevance_basis(k)
    assert feats.shape == (3, k) and feats.dtype == F64
    for n in range(1, k + 1):  # weight index n = 1..K, as the authors' MATLAB x = 1:N
        assert feats[0, n - 1].item() == pytest.approx(1 / (1 + math.exp(-(n - k / 3))), rel=1e-12)
        assert feats[1, n - 1].item() == pytest.approx(
            1 / (1 + math.exp(-(n - 2 * k / 3))), rel=1e-12
        )
        assert feats[2, n - 1].item() == 1.0


def test_optimiser_features_buffer_follows_num_basis_and_dtype():
    opt = RWPO(
        torch.zeros(2, 8, dtype=torch.float32), 1.0, beta=1.0, num_objectives=1, num_basis=4, **TINY
    )
    assert opt.features.dtype == torch.float32
    torch.testing.assert_close(opt.features, rwpo_relevance_basis(4, dtype=torch.float32))
    assert "features" in dict(opt.named_buffers())


# --------------------------------------------------------------------- learned relevance
def test_relevance_asks_for_every_objective_theta_and_trajectory_sample():
    opt = RWPO(
        torch.zeros(3, 6, dtype=F64),
        1.0,
        beta=1.0,
        num_objectives=2,
        num_samples=10,
        seed=0,
        relevance_iters=4,
        theta_samples=5,
        trajectory_samples=3,
    )
    shapes = []
    while opt.iteration == 0:
        w = opt.ask()
        shapes.append(tuple(w.shape))
        opt.tell(early_late(w))
    assert (
        shapes == [(3, 2 * 5 * 3, 6)] * 4 + [(3, 10, 6)] * 2
    )  # 4 learning iterations, then 2 updates
    assert len(opt.relevance_seconds) == 1


def test_learned_relevance_in_unit_interval_with_max_one():
    opt = learn(
        torch.zeros(4, 9, dtype=F64), relevance_iters=5, theta_samples=20, trajectory_samples=6
    )
    rel = opt.relevance  # (B, O, N)
    assert rel.shape == (4, 2, 9)
    assert bool(((rel >= 0) & (rel <= 1)).all())
    torch.testing.assert_close(rel.amax(-1), torch.ones(4, 2, dtype=F64), rtol=0, atol=1e-12)


def test_learned_relevance_profile_favours_the_right_end():
    # 8 independent problems at once: objective 0 depends on the early weights, objective 1 on
    # the late ones. Averaged over problems, each objective's profile leans to its own end.
    n = 10
    opt = learn(
        torch.zeros(8, n, dtype=F64), relevance_iters=15, theta_samples=40, trajectory_samples=10
    )
    rel = opt.relevance.mean(0)  # (O, N)
    first, last = slice(0, 3), slice(n - 3, n)
    assert rel[0, first].mean() > rel[0, last].mean() + 0.3, rel[0]
    assert rel[1, last].mean() > rel[1, first].mean() + 0.3, rel[1]
    # and relevance is monotone-ish: the late weights matter more to objective 1 than to 0
    assert rel[1, last].mean() > rel[0, last].mean() and rel[0, first].mean() > rel[1, first].mean()


def test_relevance_is_shared_by_every_dof():
    k = 5
    opt = learn(torch.zeros(2, 2 * k, dtype=F64), num_basis=k)
    rel = opt.relevance
    assert torch.equal(rel[..., :k], rel[..., k:])


def test_relevance_learned_once_by_default_then_pro_updates():
    opt = RWPO(
        torch.zeros(2, 6, dtype=F64),
        torch.tensor([1.0, 2, 3, 1, 2, 3], dtype=F64),
        beta=torch.tensor([1.0, 4.0]),
        num_objectives=2,
        num_samples=15,
        max_iter=3,
        tol=0.0,
        seed=1,
        **TINY,
    )
    while opt.iteration == 0:  # the learning and the first updates
        opt.tell(early_late(opt.ask()))
    rel = opt.relevance.clone()
    for o in range(2):  # iteration 1: no new learning, one PRO update per objective
        mean, var = opt.mean.clone(), opt.var.clone()
        w = opt.ask()
        assert w.shape == (2, 15, 6)
        costs = early_late(w)
        opt.tell(costs)
        for b, beta in enumerate((1.0, 4.0)):
            m, v = pro_update(mean[b], var[b], w[b], costs[b, :, o], rel[b, o], beta)
            torch.testing.assert_close(opt.mean[b], m, rtol=1e-14, atol=1e-14)
            torch.testing.assert_close(opt.var[b], v, rtol=1e-14, atol=1e-14)
    assert torch.equal(opt.relevance, rel) and len(opt.relevance_seconds) == 1


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_relevance_learning_survives_a_collapsed_theta_covariance(dtype):
    # few theta draws and a sharp relevance_beta put all the reward on one draw, so the
    # theta covariance becomes rank-deficient: sampling must still work (float32 included)
    for seed in range(3):
        opt = learn(
            torch.zeros(2, 4, dtype=dtype),
            seed=seed,
            relevance_iters=10,
            theta_samples=8,
            trajectory_samples=4,
            relevance_beta=50.0,
        )
        assert opt.relevance.dtype == dtype
        assert bool(torch.isfinite(opt.relevance).all())
        assert bool(((opt.relevance >= 0) & (opt.relevance <= 1)).all())


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kw, message",
    [
        ({"num_basis": 4}, "num_basis = 4 does not divide the 6 weights"),
        ({"num_basis": 0}, "does not divide"),
        ({"relevance_iters": 0}, "must be >= 1"),
        ({"theta_samples": 0}, "must be >= 1"),
        ({"trajectory_samples": 1}, "trajectory_samples must be >= 2"),
        ({"relevance_beta": 0.0}, "relevance_beta must be > 0"),
        ({"beta": -1.0}, "beta must be finite and > 0"),
    ],
)
def test_bad_rwpo_arguments_raise(kw, message):
    with pytest.raises(ValueError, match=message):
        RWPO(torch.zeros(6), 1.0, **{"beta": 1.0, "num_objectives": 2, **kw})


def test_num_objectives_is_required():
    with pytest.raises(TypeError, match="num_objectives"):
        RWPO(torch.zeros(6), 1.0, beta=1.0)
