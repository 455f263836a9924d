"""The functional PRO core against independent computations and hand-worked numbers.

``pearson_relevance`` is checked against ``np.corrcoef``; ``pro_update`` (Eq. 4-6) against
numbers written out by hand and against a plain numpy loop of the unshifted formula.
"""

import math

import numpy as np
import pytest
import torch

from protorch import PRO, pearson_relevance, pro_update, stable_rewards
from protorch.optim import noise_floor_threshold


# ----------------------------------------------------------------------------- helpers
def np_relevance(w: np.ndarray, c: np.ndarray, z: float | None = None) -> np.ndarray:
    """Reference: |corrcoef(w_n, c_o)| per pair, floored at z/sqrt(S), divided by each row's max."""
    s, n = w.shape
    o = c.shape[1]
    rho = np.zeros((o, n))
    for i in range(o):
        for j in range(n):
            rho[i, j] = abs(np.corrcoef(w[:, j], c[:, i])[0, 1])
    if z is not None:
        rho[rho < z / math.sqrt(s)] = 0.0
    top = rho.max(1, keepdims=True)
    return np.divide(rho, top, out=np.zeros_like(rho), where=top > 0)


def np_pro_update(mean, var, samples, costs, relevance, beta):
    """Reference Eq. 4-6 written as loops with the *unshifted* rewards exp(-beta * cost)."""
    r = np.exp(-beta * costs)
    new_mean = np.zeros_like(mean)
    spread = np.zeros_like(mean)
    for i in range(samples.shape[0]):
        new_mean += r[i] * samples[i]
        spread += r[i] * (samples[i] - mean) ** 2
    new_mean /= r.sum()
    spread /= r.sum()
    return new_mean, (1 - relevance) * var + relevance * spread


def correlated_data(rng, s=60, n=5, o=3):
    """Weights and objectives with a mix of strong, weak, negative and no correlation."""
    w = rng.normal(size=(s, n))
    c = np.stack(
        [
            2.0 * w[:, 0] - 0.5 * w[:, 1] + 0.1 * rng.normal(size=s),
            -3.0 * w[:, 2] + 0.3 * rng.normal(size=s),
            np.abs(w[:, 3]) + w[:, 4] + rng.normal(size=s),
        ][:o],
        axis=1,
    )
    return w, c


# ------------------------------------------------------------------- pearson_relevance
def test_pearson_matches_numpy_corrcoef(rng):
    w, c = correlated_data(rng)
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    assert got.shape == (3, 5)
    np.testing.assert_allclose(got.numpy(), np_relevance(w, c), rtol=1e-12, atol=1e-12)


def test_pearson_is_in_unit_interval_with_max_one_per_objective(rng):
    w, c = correlated_data(rng)
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    assert bool(((got >= 0) & (got <= 1)).all())
    assert torch.equal(got.amax(-1), torch.ones(3, dtype=got.dtype))


def test_pearson_negative_correlation_counts_as_relevant(rng):
    w = rng.normal(size=(40, 2))
    c = np.stack([-w[:, 0], w[:, 0]], axis=1)  # perfectly anti- and positively correlated
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    torch.testing.assert_close(got[:, 0], torch.ones(2, dtype=got.dtype))
    torch.testing.assert_close(got[0], got[1])


def test_pearson_is_invariant_to_affine_rescaling(rng):
    w, c = correlated_data(rng)
    a = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    b = pearson_relevance(torch.from_numpy(1e3 * w - 5.0), torch.from_numpy(1e-2 * c + 7.0))
    torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-9)


def test_pearson_leading_batch_dims(rng):
    ws, cs = zip(*[correlated_data(rng, s=30) for _ in range(6)])
    w = torch.from_numpy(np.stack(ws)).reshape(2, 3, 30, 5)
    c = torch.from_numpy(np.stack(cs)).reshape(2, 3, 30, 3)
    got = pearson_relevance(w, c)
    assert got.shape == (2, 3, 3, 5)
    for i in range(2):
        for j in range(3):
            ref = np_relevance(w[i, j].numpy(), c[i, j].numpy())
            np.testing.assert_allclose(got[i, j].numpy(), ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("value", [0.0, 7.3, -1e4])
def test_pearson_constant_weight_gives_zero_not_nan(rng, value):
    w, c = correlated_data(rng)
    w[:, 1] = value  # a weight that never moves: its correlation is undefined, relevance 0
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    assert not bool(got.isnan().any())
    assert torch.equal(got[:, 1], torch.zeros(3, dtype=got.dtype))
    others = [0, 2, 3, 4]
    np.testing.assert_allclose(
        got[:, others].numpy(), np_relevance(w[:, others], c), rtol=1e-12, atol=1e-12
    )


@pytest.mark.parametrize("value", [0.0, 0.1, 123.456])
def test_pearson_constant_objective_gives_zero_row_not_nan(rng, value):
    w, c = correlated_data(rng)
    c[:, 2] = value
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    assert not bool(got.isnan().any())
    assert torch.equal(got[2], torch.zeros(5, dtype=got.dtype))
    np.testing.assert_allclose(got[:2].numpy(), np_relevance(w, c[:, :2]), rtol=1e-12, atol=1e-12)


def test_pearson_everything_constant_is_all_zero():
    w = torch.full((10, 4), 3.0)
    c = torch.full((10, 2), 1.5)
    got = pearson_relevance(w, c)
    assert torch.equal(got, torch.zeros(2, 4))


def test_pearson_float32_matches_numpy(rng):
    w, c = correlated_data(rng)
    got = pearson_relevance(torch.from_numpy(w).float(), torch.from_numpy(c).float())
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), np_relevance(w, c), atol=1e-5)


@pytest.mark.parametrize("offset", [1e3, 1e4])
def test_pearson_float32_small_spread_around_a_large_mean(gen, offset):
    # PRO's probes: std ~3e-3 (variance 1e-5) around a mean of magnitude 1e3..1e4 in float32.
    # The spread is many float32 ulps wide, so w_0's correlation is real and must not be
    # mistaken for a constant weight; w_2 is exactly constant.
    eps = 3e-3 * torch.randn(200, 3, generator=gen)
    w = (offset + eps).float()
    w[:, 2] = offset
    c = (2.0 * eps[:, :1]).float()  # depends on w_0 only
    got = pearson_relevance(w, c, noise_floor=4.0)
    assert got[0, 0] == 1.0 and got[0, 1] == 0.0 and got[0, 2] == 0.0
    # without the floor, the noise correlation of w_1 matches numpy on the same float32 values
    plain = pearson_relevance(w, c)
    ref = np_relevance(w[:, :2].double().numpy(), c.double().numpy())
    np.testing.assert_allclose(plain[:, :2].numpy(), ref, atol=1e-3)
    assert plain[0, 2] == 0.0


@pytest.mark.parametrize("offset", [1e3, 1e4])
def test_pearson_float32_small_cost_spread_around_a_large_cost(gen, offset):
    # the same for the objective: float32 costs offset + 2 w_0 with w_0 of std 3e-3 vary by many
    # ulps of the offset, so w_0 is relevant; an objective that is exactly constant is not
    w = 3e-3 * torch.randn(200, 3, generator=gen)
    c = torch.stack([offset + 2.0 * w[:, 0], torch.full((200,), offset)], -1).float()  # (S, 2)
    got = pearson_relevance(w.float(), c, noise_floor=4.0)
    assert got[0, 0] == 1.0 and got[0, 1] == 0.0 and got[0, 2] == 0.0
    assert torch.equal(got[1], torch.zeros(3))
    ref = np_relevance(w.double().numpy(), c[:, :1].double().numpy())
    np.testing.assert_allclose(pearson_relevance(w.float(), c)[:1].numpy(), ref, atol=1e-3)


def test_pro_float32_moves_a_weight_whose_cost_sits_on_a_large_offset():
    # 1000 + |w_1 - 2| in float32: the relevance must see w_1 through the offset and PRO reach w_1 =
    # 2
    opt = PRO(torch.zeros(2), torch.ones(2), beta=20.0, num_samples=100, max_iter=300, seed=0)
    res = opt.minimize(lambda w: 1000.0 + (w[..., 1:] - 2.0).abs())
    assert abs(float(res.mean[1]) - 2.0) < 0.05


def test_pearson_integer_costs_are_promoted(rng):
    w = rng.normal(size=(20, 3))
    c = np.stack([np.arange(20), np.arange(20) % 3], axis=1)
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    assert got.dtype == torch.float64
    np.testing.assert_allclose(
        got.numpy(), np_relevance(w, c.astype(float)), rtol=1e-12, atol=1e-12
    )


# ------------------------------------------------------------------------ noise floor
def test_noise_floor_threshold_value():
    assert noise_floor_threshold(100, 4.0) == pytest.approx(0.4)
    assert noise_floor_threshold(200, 3.0) == pytest.approx(3 / math.sqrt(200))


def test_noise_floor_zeros_weak_correlations_and_keeps_the_rest(rng):
    s = 100
    w, c = correlated_data(rng, s=s)
    raw = np.abs(
        np.array([[np.corrcoef(w[:, j], c[:, i])[0, 1] for j in range(5)] for i in range(3)])
    )
    z = 2.5  # threshold 0.25
    assert (raw < z / math.sqrt(s)).any() and (raw >= z / math.sqrt(s)).any()
    got = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c), noise_floor=z)
    np.testing.assert_allclose(got.numpy(), np_relevance(w, c, z=z), rtol=1e-12, atol=1e-12)
    below = torch.from_numpy(raw < z / math.sqrt(s))
    assert bool((got[below] == 0).all())
    # where the maximum survives the floor, surviving entries keep their unfloored values
    plain = pearson_relevance(torch.from_numpy(w), torch.from_numpy(c))
    torch.testing.assert_close(got[~below], plain[~below])


def test_noise_floor_unrelated_weights_are_exactly_irrelevant(gen):
    # w_1..w_4 are independent of the cost: with z = 4 their sampling-noise correlations
    # (size ~1/sqrt(S)) are treated as 0, while w_0 keeps relevance 1.
    s = 200
    w = torch.randn(s, 5, generator=gen, dtype=torch.float64)
    c = (w[:, :1] - 2.0).abs()
    without = pearson_relevance(w, c)
    with_floor = pearson_relevance(w, c, noise_floor=4.0)
    assert bool((without[0, 1:] > 0).all())  # the paper's formula as written: noise > 0
    assert torch.equal(with_floor, torch.tensor([[1.0, 0, 0, 0, 0]], dtype=torch.float64))


def test_noise_floor_zero_equals_no_floor_and_huge_floor_gives_zeros(rng):
    w, c = correlated_data(rng)
    wt, ct = torch.from_numpy(w), torch.from_numpy(c)
    torch.testing.assert_close(
        pearson_relevance(wt, ct, noise_floor=0.0), pearson_relevance(wt, ct)
    )
    huge = pearson_relevance(wt, ct, noise_floor=1e6)
    assert torch.equal(huge, torch.zeros_like(huge))


def test_noise_floor_negative_raises(rng):
    w, c = correlated_data(rng)
    with pytest.raises(ValueError, match="noise_floor"):
        pearson_relevance(torch.from_numpy(w), torch.from_numpy(c), noise_floor=-1.0)


# ------------------------------------------------------------------ pearson bad input
def test_pearson_shape_mismatch_raises():
    with pytest.raises(ValueError, match=r"must agree on \(\.\.\., S\)"):
        pearson_relevance(torch.zeros(10, 3), torch.zeros(9, 2))
    with pytest.raises(ValueError, match="at least 2 dimensions"):
        pearson_relevance(torch.zeros(10), torch.zeros(10, 2))


def test_pearson_too_few_samples_raises():
    with pytest.raises(ValueError, match="at least 3 samples"):
        pearson_relevance(torch.randn(2, 3), torch.randn(2, 1))


@pytest.mark.parametrize(
    "bad, word", [(float("nan"), "NaN"), (float("inf"), "inf"), (-float("inf"), "inf")]
)
def test_pearson_non_finite_raises(bad, word):
    w, c = torch.randn(10, 3), torch.randn(10, 2)
    c_bad = c.clone()
    c_bad[4, 1] = bad
    with pytest.raises(ValueError, match=f"costs contains {word}"):
        pearson_relevance(w, c_bad)
    w_bad = w.clone()
    w_bad[0, 0] = bad
    with pytest.raises(ValueError, match=f"w contains {word}"):
        pearson_relevance(w_bad, c)


# ---------------------------------------------------------------------- stable_rewards
def test_stable_rewards_is_the_shifted_exponential():
    costs = torch.tensor([3.0, 1.0, 2.5], dtype=torch.float64)
    got = stable_rewards(costs, 2.0)
    expected = torch.exp(-2.0 * torch.tensor([2.0, 0.0, 1.5], dtype=torch.float64))
    torch.testing.assert_close(got, expected, rtol=1e-15, atol=0)
    assert got.max() == 1.0


def test_stable_rewards_normalised_equal_unshifted_formula(rng):
    costs = rng.uniform(0, 3, size=(4, 25))
    beta = 1.7
    got = stable_rewards(torch.from_numpy(costs), beta)
    got = got / got.sum(-1, keepdim=True)
    r = np.exp(-beta * costs)
    np.testing.assert_allclose(got.numpy(), r / r.sum(-1, keepdims=True), rtol=1e-12)


def test_stable_rewards_huge_costs_are_finite():
    small = torch.tensor([0.0, 0.25, 0.5, 1.0], dtype=torch.float64)
    costs = 1e6 + small
    naive = torch.exp(-10.0 * costs)
    assert bool((naive == 0).all())  # the unshifted formula underflows: 0 / 0 would follow
    got = stable_rewards(costs, 10.0)
    assert bool(torch.isfinite(got).all()) and got.max() == 1.0
    torch.testing.assert_close(got, torch.exp(-10.0 * small), rtol=1e-9, atol=0)


def test_stable_rewards_per_problem_beta_and_dim():
    costs = torch.tensor([[0.0, 1.0, 2.0], [5.0, 6.0, 9.0]], dtype=torch.float64)  # (B=2, S=3)
    beta = torch.tensor([1.0, 0.5], dtype=torch.float64)
    got = stable_rewards(costs, beta)
    torch.testing.assert_close(
        got[0], torch.exp(-torch.tensor([0.0, 1.0, 2.0], dtype=torch.float64))
    )
    torch.testing.assert_close(
        got[1], torch.exp(-0.5 * torch.tensor([0.0, 1.0, 4.0], dtype=torch.float64))
    )
    # the same with samples on dim 0: (S, B)
    torch.testing.assert_close(stable_rewards(costs.T, beta, dim=0), got.T)


@pytest.mark.parametrize("beta", [0.0, -1.0, float("nan"), float("inf"), torch.tensor([1.0, -2.0])])
def test_stable_rewards_bad_beta_raises(beta):
    with pytest.raises(ValueError, match="beta must be finite and > 0"):
        stable_rewards(torch.zeros(2, 3), beta)


def test_beta_of_the_wrong_shape_is_named():
    costs = torch.zeros(2, 3)  # (B=2, S=3)
    with pytest.raises(
        ValueError,
        match=r"beta of shape \(3,\) does not broadcast against the costs' problems \(2,\)",
    ):
        stable_rewards(costs, torch.ones(3))
    with pytest.raises(ValueError, match=r"beta of shape \(4,\)"):
        pro_update(
            torch.zeros(2, 1),
            torch.ones(2, 1),
            torch.zeros(2, 3, 1),
            costs,
            torch.ones(2, 1),
            torch.ones(4),
        )


@pytest.mark.parametrize("bad, word", [(float("nan"), "NaN"), (float("inf"), "inf")])
def test_stable_rewards_non_finite_costs_raise(bad, word):
    with pytest.raises(ValueError, match=f"costs contains {word}"):
        stable_rewards(torch.tensor([0.0, bad, 1.0]), 1.0)


# -------------------------------------------------------------------------- pro_update
def hand_example(dtype=torch.float64):
    """Three samples of two weights; costs chosen so that R = (1, 1/2, 1/4) at beta = 2.

    Normalised rewards: (4/7, 2/7, 1/7).
    Eq. 4: mean' = 4/7 (1, 0) + 2/7 (-1, 2) + 1/7 (2, 1) = (4/7, 5/7).
    Eq. 5 around the OLD mean (0, 1):
        C_1 = 4/7 * 1 + 2/7 * 1 + 1/7 * 4 = 10/7,
        C_2 = 4/7 * 1 + 2/7 * 1 + 1/7 * 0 = 6/7.
    """

    def t(x):
        return torch.tensor(x, dtype=dtype)

    mean = t([0.0, 1.0])
    var = t([1.0, 4.0])
    samples = t([[1.0, 0.0], [-1.0, 2.0], [2.0, 1.0]])
    costs = t([0.0, math.log(2) / 2, math.log(4) / 2])
    return mean, var, samples, costs, 2.0


def test_pro_update_hand_computed_partial_relevance():
    mean, var, samples, costs, beta = hand_example()
    f = torch.tensor([0.5, 0.25], dtype=torch.float64)
    new_mean, new_var = pro_update(mean, var, samples, costs, f, beta)
    # Eq. 6: var' = (1 - f) var + f C
    #             = (0.5 * 1 + 0.5 * 10/7, 0.75 * 4 + 0.25 * 6/7) = (17/14, 45/14)
    torch.testing.assert_close(
        new_mean, torch.tensor([4 / 7, 5 / 7], dtype=torch.float64), rtol=1e-14, atol=1e-14
    )
    torch.testing.assert_close(
        new_var, torch.tensor([17 / 14, 45 / 14], dtype=torch.float64), rtol=1e-14, atol=1e-14
    )


def test_pro_update_relevance_one_is_spread_around_old_mean():
    mean, var, samples, costs, beta = hand_example()
    new_mean, new_var = pro_update(
        mean, var, samples, costs, torch.ones(2, dtype=torch.float64), beta
    )
    torch.testing.assert_close(
        new_var, torch.tensor([10 / 7, 6 / 7], dtype=torch.float64), rtol=1e-14, atol=1e-14
    )
    # not the spread around the new mean: 10/7 - (4/7)^2 = 54/49 and 6/7 - (5/7 - 1)^2 = 38/49
    # (they differ by (mean' - mean)^2 = (16/49, 4/49))
    around_new = torch.tensor([54 / 49, 38 / 49], dtype=torch.float64)
    torch.testing.assert_close(new_var - around_new, (new_mean - mean) ** 2, rtol=1e-14, atol=1e-14)
    assert bool(((new_var - around_new).abs() > 0.05).all())


def test_pro_update_relevance_zero_keeps_variance_exactly():
    mean, var, samples, costs, beta = hand_example()
    new_mean, new_var = pro_update(
        mean, var, samples, costs, torch.zeros(2, dtype=torch.float64), beta
    )
    assert torch.equal(new_var, var)
    torch.testing.assert_close(new_mean, torch.tensor([4 / 7, 5 / 7], dtype=torch.float64))


def test_pro_update_shift_and_cost_scale_invariance():
    mean, var, samples, costs, beta = hand_example()
    f = torch.tensor([0.5, 0.25], dtype=torch.float64)
    ref = pro_update(mean, var, samples, costs, f, beta)
    shifted = pro_update(mean, var, samples, costs + 1e6, f, beta)  # huge costs: still the same
    for a, b in zip(ref, shifted):
        assert bool(torch.isfinite(b).all())
        torch.testing.assert_close(a, b, rtol=1e-8, atol=1e-8)
    halved = pro_update(mean, var, samples, 2 * costs, f, beta / 2)  # only beta * cost matters
    for a, b in zip(ref, halved):
        torch.testing.assert_close(a, b, rtol=1e-14, atol=1e-14)


def test_pro_update_costs_with_trailing_objective_dim():
    mean, var, samples, costs, beta = hand_example()
    f = torch.tensor([0.5, 0.25], dtype=torch.float64)
    for a, b in zip(
        pro_update(mean, var, samples, costs, f, beta),
        pro_update(mean, var, samples, costs[:, None], f, beta),
    ):
        assert torch.equal(a, b)


def test_pro_update_matches_numpy_unshifted_formula(rng):
    n, s = 6, 40
    mean = rng.normal(size=n)
    var = rng.uniform(0.5, 2.0, size=n)
    f = rng.uniform(0, 1, size=n)
    samples = mean + rng.normal(size=(s, n)) * np.sqrt(var * f)
    costs = ((samples - 1.0) ** 2).sum(1)
    beta = 0.7
    ref_mean, ref_var = np_pro_update(mean, var, samples, costs, f, beta)
    got_mean, got_var = pro_update(*map(torch.from_numpy, (mean, var, samples, costs, f)), beta)
    np.testing.assert_allclose(got_mean.numpy(), ref_mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got_var.numpy(), ref_var, rtol=1e-12, atol=1e-12)


def test_pro_update_huge_costs_finite_where_unshifted_underflows(rng):
    n, s = 3, 10
    mean, var, f = np.zeros(n), np.ones(n), np.ones(n)
    samples = rng.normal(size=(s, n))
    costs = 1e6 * (1.0 + np.arange(s))  # exp(-cost) underflows for every sample
    with np.errstate(invalid="ignore"):
        naive_mean, _ = np_pro_update(mean, var, samples, costs, f, 1.0)
    assert np.isnan(naive_mean).all()
    got_mean, got_var = pro_update(*map(torch.from_numpy, (mean, var, samples, costs, f)), 1.0)
    # the best sample takes all the weight: the others are exp(-1e6) behind it
    np.testing.assert_array_equal(got_mean.numpy(), samples[0])
    np.testing.assert_allclose(got_var.numpy(), samples[0] ** 2, rtol=1e-15)


def test_pro_update_irrelevant_weight_keeps_variance_and_mean_over_many_steps(gen):
    # 200 updates in a row where weight 1 has relevance 0: its samples sit exactly on the mean
    # (drawn with variance var * 0), its variance never changes and its mean stays put.
    mean = torch.tensor([0.3, -1.7], dtype=torch.float64)
    var = torch.tensor([1.0, 2.5], dtype=torch.float64)
    f = torch.tensor([1.0, 0.0], dtype=torch.float64)
    for _ in range(200):
        w = mean + torch.randn(50, 2, generator=gen, dtype=torch.float64) * (var * f).sqrt()
        mean, var = pro_update(mean, var, w, (w[:, 0] - 2.0).abs(), f, 5.0)
    assert var[1].item() == 2.5
    assert mean[1].item() == pytest.approx(-1.7, rel=1e-13)
    assert abs(mean[0].item() - 2.0) < 0.05 and var[0].item() < 1e-3


def test_pro_update_batch_dims_match_a_loop(gen):
    b1, b2, s, n = 2, 3, 16, 4
    dt = {"dtype": torch.float64}
    mean = torch.randn(b1, b2, n, generator=gen, **dt)
    var = torch.rand(b1, b2, n, generator=gen, **dt) + 0.1
    f = torch.rand(b1, b2, n, generator=gen, **dt)
    samples = mean[..., None, :] + torch.randn(b1, b2, s, n, generator=gen, **dt)
    costs = samples.pow(2).sum(-1)
    beta = torch.tensor([[0.5, 1.0, 2.0], [4.0, 8.0, 16.0]], **dt)  # one beta per problem
    got_mean, got_var = pro_update(mean, var, samples, costs, f, beta)
    assert got_mean.shape == got_var.shape == (b1, b2, n)
    for i in range(b1):
        for j in range(b2):
            m, v = pro_update(
                mean[i, j], var[i, j], samples[i, j], costs[i, j], f[i, j], float(beta[i, j])
            )
            torch.testing.assert_close(got_mean[i, j], m, rtol=1e-14, atol=1e-14)
            torch.testing.assert_close(got_var[i, j], v, rtol=1e-14, atol=1e-14)
    # a shared float beta is the same as a constant per-problem beta
    a = pro_update(mean, var, samples, costs, f, 2.0)
    b = pro_update(mean, var, samples, costs, f, torch.full((b1, b2), 2.0, **dt))
    for x, y in zip(a, b):
        torch.testing.assert_close(x, y, rtol=1e-15, atol=0)


def test_pro_update_float32():
    mean, var, samples, costs, beta = (
        x.float() if torch.is_tensor(x) else x for x in hand_example()
    )
    new_mean, new_var = pro_update(mean, var, samples, costs, torch.tensor([0.5, 0.25]), beta)
    assert new_mean.dtype == new_var.dtype == torch.float32
    torch.testing.assert_close(new_mean, torch.tensor([4 / 7, 5 / 7]))
    torch.testing.assert_close(new_var, torch.tensor([17 / 14, 45 / 14]))


# ---------------------------------------------------------------- pro_update bad input
def _args():
    mean, var, samples, costs, beta = hand_example()
    return {
        "mean": mean,
        "var": var,
        "samples": samples,
        "costs": costs,
        "relevance": torch.ones(2, dtype=torch.float64),
        "beta": beta,
    }


@pytest.mark.parametrize("beta", [0.0, -3.0, float("nan"), torch.tensor(-1.0)])
def test_pro_update_bad_beta_raises(beta):
    with pytest.raises(ValueError, match="beta must be finite and > 0"):
        pro_update(**{**_args(), "beta": beta})


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("costs", torch.tensor([0.0, float("nan"), 1.0]), "costs contains NaN"),
        ("costs", torch.tensor([0.0, float("inf"), 1.0]), "costs contains inf"),
        ("samples", torch.tensor([[1.0, float("inf")], [0, 0], [0, 0]]), "samples contains inf"),
        ("mean", torch.tensor([float("nan"), 0.0]), "mean contains NaN"),
        ("var", torch.tensor([1.0, -1.0]), "var must be >= 0"),
        ("relevance", torch.tensor([0.5, 1.5]), r"relevance must lie in \[0, 1\]"),
        ("relevance", torch.tensor([-0.1, 0.5]), r"relevance must lie in \[0, 1\]"),
        ("var", torch.ones(3), "must share a shape"),
        ("relevance", torch.ones(1, 2), "must share a shape"),
        ("samples", torch.zeros(3, 3), r"samples must be \(\.\.\., S, 2\)"),
        ("costs", torch.zeros(4), r"costs must be \(\.\.\., S\)"),
        ("costs", torch.zeros(3, 2), r"costs must be \(\.\.\., S\)"),
    ],
)
def test_pro_update_bad_input_raises(key, value, message):
    args = _args()
    args[key] = value.to(torch.float64)
    with pytest.raises(ValueError, match=message):
        pro_update(**args)


def test_pro_update_promotes_integer_tensors():
    """Integer inputs are the same numbers as float ones: the step must not truncate them."""
    mean, var = torch.tensor([1, 0, 1]), torch.tensor([1, 1, 1])
    samples = torch.tensor([[2, 0, 1], [1, 1, 0], [3, 0, 1], [0, 1, 2]])
    costs, rel = torch.tensor([1, 3, 2, 4]), torch.tensor([1, 1, 1])
    got = pro_update(mean, var, samples, costs, rel, 1.0)
    want = pro_update(
        mean.double(), var.double(), samples.double(), costs.double(), rel.double(), 1.0
    )
    for g, w in zip(got, want):
        assert g.dtype == torch.float64
        torch.testing.assert_close(g, w, rtol=0, atol=0)
    assert float(got[0].abs().sum()) > 0


def test_stable_rewards_of_integer_costs_keep_a_fractional_beta():
    got = stable_rewards(torch.tensor([3, 1, 2]), 0.5)
    torch.testing.assert_close(
        got, torch.exp(-0.5 * torch.tensor([2.0, 0.0, 1.0], dtype=torch.float64))
    )
