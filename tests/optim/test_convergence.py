"""The stop rules: protorch's mean-cost window and the authors' every-sample rule with
thresholds."""

import pytest
import torch

from protorch import PRO
from protorch.optim.convergence import AuthorsRule, MeanWindow, make_rule

F64 = torch.float64


def history(mean, low, high):
    """Lists of (B, O) per iteration from (I, B, O) tensors."""
    return {"cost": list(mean), "cost_min": list(low), "cost_max": list(high)}


def test_mean_window_settles_on_the_mean_while_the_authors_rule_waits_for_every_sample():
    w = 5
    mean = torch.full((w, 2, 3), 0.5, dtype=F64)  # (I, B, O) constant mean costs
    low = mean - torch.tensor([0.0, 0.1], dtype=F64)[None, :, None]  # problem 1: samples spread
    high = mean + torch.tensor([0.0, 0.1], dtype=F64)[None, :, None]
    h = history(mean, low, high)
    assert MeanWindow(1e-3, w)(h).tolist() == [True, True]
    assert AuthorsRule(1e-3, w)(h).tolist() == [True, False]


def test_mean_window_is_max_minus_min_of_the_means_over_the_window():
    mean = torch.tensor([[[0.0]], [[0.0004]], [[0.0009]], [[0.002]]], dtype=F64)  # (4, 1, 1)
    h = history(mean, mean, mean)
    assert MeanWindow(1e-3, 3)(h).tolist() == [False]  # 0.002 - 0.0004 > 1e-3
    h = history(mean[:3], mean[:3], mean[:3])
    assert MeanWindow(1e-3, 3)(h).tolist() == [True]  # 0.0009 - 0 <= 1e-3
    assert MeanWindow(0.0, 3)(h).tolist() == [False]  # tol 0 disables the rule


def test_authors_thresholds_on_the_last_mean_and_best_sample():
    c = torch.tensor([0.004, 0.95, 0.006], dtype=F64)  # start, clearance cost, end
    mean = c.expand(5, 1, 3).clone()
    low = mean.clone()
    h = history(mean, low, mean)
    assert AuthorsRule(1e-3, 5, mean_at_most={0: 0.005})(h).tolist() == [True]
    assert AuthorsRule(1e-3, 5, mean_at_most={0: 0.005, 2: 0.005})(h).tolist() == [False]
    assert AuthorsRule(1e-3, 5, best_at_most={1: 0.9})(h).tolist() == [False]
    low[-1, 0, 1] = 0.89  # one sample clears the wall by 0.11 (the window spread then exceeds tol)
    h = history(mean, low, mean)
    assert AuthorsRule(1.0, 5, best_at_most={1: 0.9})(h).tolist() == [True]
    with pytest.raises(ValueError, match="objective 3"):
        AuthorsRule(1e-3, 5, mean_at_most={3: 0.1})(h)


def test_bad_rules_are_refused():
    with pytest.raises(ValueError, match="convergence must be one of"):
        make_rule("median", tol=1e-3, window=5)
    with pytest.raises(ValueError, match="tol >= 0"):
        AuthorsRule(-1.0, 5)
    with pytest.raises(ValueError, match="window >= 1"):
        MeanWindow(1e-3, 0)
    with pytest.raises(ValueError, match="objective indices"):
        AuthorsRule(1e-3, 5, mean_at_most={-1: 0.1})
    with pytest.raises(ValueError, match="convergence must be one of"):
        PRO(torch.zeros(3, dtype=F64), torch.ones(3, dtype=F64), beta=1.0, convergence="sometimes")


def quadratic(w):
    return torch.stack([(w[..., 0] - 1) ** 2, (w[..., 1] + 1) ** 2], -1)  # (..., 2)


def run(convergence, seed=0):
    opt = PRO(
        torch.zeros(4, 3, dtype=F64),
        torch.ones(4, 3, dtype=F64),
        beta=50.0,
        num_samples=50,
        relevance_samples=50,
        max_iter=150,
        seed=seed,
        convergence=convergence,
        noise_floor=4.0,
    )
    return opt.minimize(quadratic)


@pytest.mark.slow
def test_pro_default_is_the_mean_rule_and_the_authors_rule_stops_where_every_sample_settled():
    default, same = run("mean"), run(MeanWindow(1e-3, 5))
    assert torch.equal(default.mean, same.mean) and torch.equal(default.converged, same.converged)
    authors = run("authors")
    h = authors.history  # cost / cost_min / cost_max (I, B, O), mean (I, B, N)
    assert bool((h["cost_min"] <= h["cost"] + 1e-12).all()) and bool(
        (h["cost"] <= h["cost_max"] + 1e-12).all()
    )
    assert bool(authors.converged.any()), "the test problem should converge under the authors' rule"
    for b in torch.nonzero(authors.converged).flatten().tolist():
        ok = [
            bool(
                (
                    (h["cost_max"][i - 5 : i, b].amax(0) - h["cost_min"][i - 5 : i, b].amin(0))
                    <= 1e-3
                ).all()
            )
            for i in range(5, h["cost"].shape[0] + 1)
        ]
        first = ok.index(True) + 5  # iterations done when the rule first held
        frozen = h["mean"][first - 1 :, b]  # (I - first + 1, N)
        assert torch.equal(frozen, frozen[:1].expand_as(frozen))  # it stopped moving there
    # every sample within tol implies the mean within tol: the authors' rule never stops a problem
    # the mean rule would keep running (both runs draw the same samples until one of them stops)
    assert bool((authors.converged <= default.converged).all())
