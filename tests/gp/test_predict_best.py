"""Label-aware inference of the environment map (EnvMap.predict_best): every label's mean is
predicted and scored, the lowest score wins per query, labels are never averaged."""

from __future__ import annotations

import pytest
import torch

from protorch.gp import make_env_map

from .reference import BACKENDS

F64 = torch.float64


@pytest.fixture(params=BACKENDS)
def two_class_map(request):
    """Label 0 maps every environment to weights ~ +1, label 1 to ~ -1 (same environments)."""
    e = torch.linspace(0, 1, 6, dtype=F64)[:, None]  # (6, 1)
    mu = torch.cat([torch.ones(6, 3, dtype=F64), -torch.ones(6, 3, dtype=F64)])  # (12, 3)
    gp = make_env_map(request.param, 5.0)
    gp.fit(
        torch.cat([e, e]), mu, torch.full((12, 3), 1e-4, dtype=F64), torch.tensor([0] * 6 + [1] * 6)
    )
    return gp


def test_the_lowest_score_wins_per_query(two_class_map):
    q = torch.tensor([[0.1], [0.5], [0.9]], dtype=F64)

    def score(mu, env):  # prefer +1 weights for env < 0.5, -1 weights above
        want = torch.where(env[:, 0] < 0.5, 1.0, -1.0)[:, None]
        return (mu - want).square().sum(-1)

    best = two_class_map.predict_best(q, score)
    assert best.label.tolist() == [0, 1, 1] and best.candidates.tolist() == [0, 1]
    assert best.scores.shape == (3, 2) and best.var.shape == (3, 3)
    for i, k in enumerate(
        best.label.tolist()
    ):  # the chosen label's own prediction, never an average
        mu_k, var_k = two_class_map.predict(q[i : i + 1], labels=k)
        torch.testing.assert_close(best.mean[i], mu_k[0])
        torch.testing.assert_close(best.var[i], var_k[0])
        torch.testing.assert_close(best.scores[i, k], score(mu_k, q[i : i + 1])[0])
    only = two_class_map.predict_best(q, score, candidates=[1], need_var=False)
    assert only.label.tolist() == [1, 1, 1] and only.var is None


def test_non_finite_scores_lose_and_bad_scores_are_refused(two_class_map):
    q = torch.tensor([[0.2], [0.7]], dtype=F64)
    best = two_class_map.predict_best(q, lambda mu, e: torch.where(mu[:, 0] > 0, float("nan"), 1.0))
    assert best.label.tolist() == [1, 1] and bool(torch.isinf(best.scores[:, 0]).all())
    with pytest.raises(ValueError, match=r"score must return \(4,\)"):
        two_class_map.predict_best(q, lambda mu, e: mu.sum())
    with pytest.raises(ValueError, match="no known environment has label"):
        two_class_map.predict_best(q, lambda mu, e: mu.sum(-1), candidates=[0, 7])
    with pytest.raises(ValueError, match="E must be"):
        two_class_map.predict_best(torch.zeros(2, 3, dtype=F64), lambda mu, e: mu.sum(-1))


def test_the_checked_label_aware_mean_prefers_a_class_whose_mean_passes_the_tasks_check(
    two_class_map,
):
    """label_aware_mean(check=True): a class whose mean fails task.success loses to one whose mean
    passes, whatever their costs; between two of a kind (both pass, both fail) the lower cost wins;
    check=False is the costs alone."""
    from protorch.gp.model import INFEASIBLE, label_aware_mean

    class Identity:  # a "ProMP" whose trajectory is its weights as one step of 3 dofs
        basis = torch.zeros(1, dtype=F64)

        def trajectory(self, w):
            return w[..., None, :]  # (P, 1, 3)

    # costs prefer +1 weights (label 0); success: a positive first weight, except where env > 0.7
    class Task:
        def costs(self, traj, env):
            return (traj[:, 0] - 1.0).square()  # (P, 3)

        def success(self, traj, env):
            return (traj[:, 0, 0] < 0) | (env[:, 0] > 0.7)

    q = torch.tensor([[0.2], [0.5], [0.9]], dtype=F64)
    plain = label_aware_mean(two_class_map, Identity(), Task(), q, dtype=F64)
    checked = label_aware_mean(two_class_map, Identity(), Task(), q, dtype=F64, check=True)
    assert plain.label.tolist() == [0, 0, 0]  # the costs alone: label 0 everywhere
    assert checked.label.tolist() == [
        1,
        1,
        0,
    ]  # label 0 fails the check below 0.7; both pass at 0.9
    torch.testing.assert_close(checked.scores[:2, 0], plain.scores[:2, 0] + INFEASIBLE)
    torch.testing.assert_close(checked.scores[:, 1], plain.scores[:, 1])
