"""ProMP: basis, ridge fit, ML distribution, sampling, conditioning, buffers and bad input."""

import numpy as np
import pytest
import torch

from protorch import ProMP
from protorch.primitives.promp import gaussian_basis, resample

F64 = torch.float64


def make(num_dof=2, num_basis=6, num_steps=50, **kw) -> ProMP:
    return ProMP(num_dof, num_basis, num_steps, **kw)


def fitted(gen, n=8, full_cov=False, **kw) -> ProMP:
    """A ProMP fitted to ``n`` demonstrations generated from random weights."""
    promp = make(**kw)
    w = 1.5 * torch.randn(n, promp.num_weights, generator=gen, dtype=F64)
    return promp.fit(promp.trajectory(w), full_cov=full_cov)


# --------------------------------------------------------------------------- basis
def test_basis_is_normalised_gaussian():
    promp = make(num_dof=1, num_basis=5, num_steps=11, width=0.2)
    assert promp.basis.shape == (11, 5)
    torch.testing.assert_close(promp.basis.sum(-1), torch.ones(11, dtype=F64))
    # independent evaluation at one phase
    z, c = 0.3, np.linspace(0, 1, 5)
    g = np.exp(-0.5 * ((z - c) / 0.2) ** 2)
    np.testing.assert_allclose(
        promp.basis_at(torch.tensor([z], dtype=F64)).numpy()[0], g / g.sum(), rtol=1e-12
    )
    np.testing.assert_allclose(
        promp.basis[3].numpy(),
        promp.basis_at(torch.tensor([0.3], dtype=F64))[0].numpy(),
        rtol=1e-12,
    )
    assert make(num_basis=11).width == pytest.approx(0.1)  # default: spacing of the centres


def test_gaussian_basis_rows_sum_to_one():
    b = gaussian_basis(torch.linspace(0, 1, 7, dtype=F64), torch.linspace(0, 1, 4, dtype=F64), 0.3)
    torch.testing.assert_close(b.sum(-1), torch.ones(7, dtype=F64))


# --------------------------------------------------------------------------- trajectory
def test_trajectory_is_phi_times_w_per_dof(gen):
    promp = make(num_dof=3, num_basis=4, num_steps=9)
    w = torch.randn(promp.num_weights, generator=gen, dtype=F64)
    tau = promp.trajectory(w)
    assert tau.shape == (9, 3)
    phi = promp.basis.numpy()
    for d in range(3):  # DoF-major layout: w[d * K + k]
        np.testing.assert_allclose(
            tau[:, d].numpy(), phi @ w[d * 4 : (d + 1) * 4].numpy(), rtol=1e-12, atol=1e-12
        )


@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (2, 1, 4)])
def test_trajectory_any_leading_batch_dims(gen, batch):
    promp = make()
    w = torch.randn(*batch, promp.num_weights, generator=gen, dtype=F64)
    tau = promp.trajectory(w)
    assert tau.shape == (*batch, promp.num_steps, promp.num_dof)
    flat = w.reshape(-1, promp.num_weights)
    ref = torch.stack([promp.trajectory(x) for x in flat]).reshape(tau.shape)
    torch.testing.assert_close(tau, ref, rtol=1e-14, atol=1e-14)


def test_trajectory_at_phases(gen):
    promp = make()
    w = torch.randn(promp.num_weights, generator=gen, dtype=F64)
    idx = [0, 17, 49]
    at = promp.trajectory(w, phase=promp.phase[idx])
    torch.testing.assert_close(at, promp.trajectory(w)[idx], rtol=1e-12, atol=1e-12)


def test_trajectory_wrong_number_of_weights_raises():
    promp = make()
    with pytest.raises(ValueError, match=f"w must end in {promp.num_weights} weights"):
        promp.trajectory(torch.zeros(3, promp.num_weights + 1))


# -------------------------------------------------------------------------------- fit
def test_fit_recovers_known_weights(gen):
    promp = make(num_dof=2, num_basis=8, num_steps=100, ridge=1e-12)
    w_true = torch.randn(5, promp.num_weights, generator=gen, dtype=F64)
    w = promp.weights(promp.trajectory(w_true))
    assert w.shape == (5, 16)
    torch.testing.assert_close(w, w_true, rtol=0, atol=1e-6)


def test_fit_accepts_a_list_and_a_single_2d_demo(gen):
    promp = make()
    w_true = torch.randn(3, promp.num_weights, generator=gen, dtype=F64)
    demos = promp.trajectory(w_true)
    torch.testing.assert_close(promp.weights(list(demos)), promp.weights(demos))
    torch.testing.assert_close(promp.weights(demos[0]), promp.weights(demos[:1]))
    one_dof = make(num_dof=1)
    w1 = torch.randn(one_dof.num_weights, generator=gen, dtype=F64)
    y = one_dof.trajectory(w1)[:, 0]  # (T,) is accepted for a 1-DoF ProMP
    torch.testing.assert_close(one_dof.weights([y])[0], w1, rtol=0, atol=1e-6)


def test_demos_of_different_lengths_are_resampled(gen):
    promp = make(num_dof=2, num_basis=6, num_steps=100, ridge=1e-12)
    w_true = torch.randn(3, promp.num_weights, generator=gen, dtype=F64)
    # lengths with (T_i - 1) a multiple of 99 hit the common phases exactly: exact recovery
    exact = [
        promp.trajectory(w_true[i], phase=torch.linspace(0, 1, t, dtype=F64))
        for i, t in enumerate((199, 100, 298))
    ]
    torch.testing.assert_close(promp.weights(exact), w_true, rtol=0, atol=1e-6)
    # arbitrary lengths: linear interpolation, so close but not exact
    odd = [
        promp.trajectory(w_true[i], phase=torch.linspace(0, 1, t, dtype=F64))
        for i, t in enumerate((137, 61, 250))
    ]
    w = promp.weights(odd)
    assert (w - w_true).abs().max() < 0.05
    tau_err = (promp.trajectory(w) - promp.trajectory(w_true)).abs().max()
    assert tau_err < 5e-3


def test_resample_is_linear_interpolation():
    y = torch.stack([torch.arange(5.0, dtype=F64), torch.arange(5.0, dtype=F64) ** 2], -1)  # (5, 2)
    out = resample(y, 9)  # half steps
    torch.testing.assert_close(out[:, 0], torch.arange(0, 4.5, 0.5, dtype=F64))
    torch.testing.assert_close(out[1::2, 1], torch.tensor([0.5, 2.5, 6.5, 12.5], dtype=F64))
    torch.testing.assert_close(out[::2], y)
    assert resample(y, 5) is y


def test_fit_ml_mean_and_biased_variance_match_numpy(gen):
    promp = make()
    demos = promp.trajectory(torch.randn(7, promp.num_weights, generator=gen, dtype=F64))
    w = promp.weights(demos).numpy()
    promp.fit(demos)
    np.testing.assert_allclose(promp.mean.numpy(), w.mean(0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(promp.var.numpy(), w.var(0, ddof=0), rtol=1e-10, atol=1e-12)
    off = promp.cov - torch.diag(promp.var)
    assert torch.equal(off, torch.zeros_like(off))  # diagonal by default
    assert bool(promp.fitted)


def test_fit_full_covariance_matches_numpy(gen):
    promp = make()
    demos = promp.trajectory(torch.randn(9, promp.num_weights, generator=gen, dtype=F64))
    w = promp.weights(demos).numpy()
    promp.fit(demos, full_cov=True)
    np.testing.assert_allclose(
        promp.cov.numpy(), np.cov(w, rowvar=False, bias=True), rtol=1e-10, atol=1e-12
    )
    torch.testing.assert_close(promp.cov, promp.cov.T, rtol=0, atol=0)


def test_fit_min_var_adds_to_the_diagonal(gen):
    promp = make()
    demos = promp.trajectory(torch.randn(4, promp.num_weights, generator=gen, dtype=F64))
    base = make().fit(demos).var
    torch.testing.assert_close(promp.fit(demos, min_var=1e-3).var, base + 1e-3)


def test_set_distribution_from_var_and_cov():
    promp = make(num_dof=1, num_basis=3)
    promp.set_distribution(torch.tensor([1.0, 2, 3]), var=torch.tensor([0.1, 0.2, 0.3]))
    torch.testing.assert_close(promp.cov, torch.diag(torch.tensor([0.1, 0.2, 0.3], dtype=F64)))
    cov = torch.tensor([[1.0, 0.5, 0], [0.5, 2, 0], [0, 0, 3]])
    promp.set_distribution(torch.zeros(3), cov=cov)
    torch.testing.assert_close(promp.cov, cov.to(F64))
    with pytest.raises(ValueError, match="exactly one of var or cov"):
        promp.set_distribution(torch.zeros(3))
    with pytest.raises(ValueError, match="var must be >= 0"):
        promp.set_distribution(torch.zeros(3), var=torch.tensor([1.0, -1, 1]))
    with pytest.raises(ValueError, match=r"mean must be \(3,\)"):
        promp.set_distribution(torch.zeros(4), var=torch.ones(4))
    with pytest.raises(ValueError, match="variances >= 0 on its diagonal"):
        promp.set_distribution(torch.zeros(3), cov=-torch.eye(3))
    with pytest.raises(ValueError, match="cov must be symmetric"):
        promp.set_distribution(torch.zeros(3), cov=torch.eye(3) + torch.triu(torch.ones(3, 3), 1))
    torch.testing.assert_close(promp.cov, cov.to(F64))  # the refused calls changed nothing


# ------------------------------------------------------------------ sample, mean, std
def test_sample_statistics_diagonal(gen):
    promp = fitted(gen)
    w = promp.sample(40000, generator=torch.Generator().manual_seed(1))
    assert w.shape == (40000, promp.num_weights) and w.dtype == F64
    std = promp.var.sqrt()
    assert ((w.mean(0) - promp.mean).abs() < 4 * std / 200).all()
    torch.testing.assert_close(w.var(0), promp.var, rtol=0.05, atol=1e-12)
    corr = torch.corrcoef(w.T) - torch.eye(promp.num_weights, dtype=F64)
    assert corr.abs().max() < 0.03


def test_sample_statistics_full_cov(gen):
    promp = fitted(gen, n=20, full_cov=True)
    w = promp.sample(40000, generator=torch.Generator().manual_seed(2))
    emp = torch.cov(w.T)
    scale = promp.var.sqrt()
    # compare correlations and variances (scale-free)
    torch.testing.assert_close(
        emp / (scale[:, None] * scale[None]),
        promp.cov / (scale[:, None] * scale[None]),
        rtol=0,
        atol=0.04,
    )
    torch.testing.assert_close(w.mean(0), promp.mean, rtol=0, atol=float(4 * scale.max() / 200))


def test_sample_and_condition_with_rank_deficient_full_cov(gen):
    # the paper's Fig. 4 set-up: 5 demonstrations, 2 DoF x 10 weights -> a rank-4 covariance
    promp = ProMP(2, 10, 100)
    promp.fit(promp.trajectory(torch.randn(5, 20, generator=gen, dtype=F64)), full_cov=True)
    assert torch.linalg.matrix_rank(promp.cov).item() == 4
    w = promp.sample(20000, generator=torch.Generator().manual_seed(4))
    assert bool(torch.isfinite(w).all())
    torch.testing.assert_close(
        torch.cov(w.T), promp.cov, rtol=0, atol=0.03 * float(promp.cov.abs().max())
    )
    out = promp.condition(promp.phase[50], torch.tensor([1.0, 2.0], dtype=F64))  # y_cov = 0
    torch.testing.assert_close(
        out.mean_trajectory()[50], torch.tensor([1.0, 2.0], dtype=F64), rtol=0, atol=1e-6
    )


def test_sample_is_reproducible_with_a_generator(gen):
    promp = fitted(gen)
    a = promp.sample(10, generator=torch.Generator().manual_seed(5))
    b = promp.sample(10, generator=torch.Generator().manual_seed(5))
    assert torch.equal(a, b)


def test_mean_trajectory_is_trajectory_of_mean(gen):
    promp = fitted(gen)
    torch.testing.assert_close(promp.mean_trajectory(), promp.trajectory(promp.mean))


@pytest.mark.parametrize("full_cov", [False, True])
def test_std_trajectory_matches_formula_and_monte_carlo(gen, full_cov):
    promp = fitted(gen, n=20, full_cov=full_cov)
    std = promp.std_trajectory()
    assert std.shape == (promp.num_steps, promp.num_dof)
    # exact: diag(Phi_d Sigma_dd Phi_d^T) per DoF, computed independently in numpy
    phi, cov, k = promp.basis.numpy(), promp.cov.numpy(), promp.num_basis
    for d in range(promp.num_dof):
        block = cov[d * k : (d + 1) * k, d * k : (d + 1) * k]
        np.testing.assert_allclose(
            std[:, d].numpy(), np.sqrt(np.diag(phi @ block @ phi.T)), rtol=1e-10
        )
    # Monte Carlo
    tau = promp.trajectory(promp.sample(20000, generator=torch.Generator().manual_seed(3)))
    torch.testing.assert_close(tau.std(0), std, rtol=0.05, atol=1e-9)


def test_unfitted_promp_raises():
    promp = make()
    with pytest.raises(RuntimeError, match="no weight distribution yet"):
        promp.sample(3)
    with pytest.raises(RuntimeError, match="no weight distribution yet"):
        promp.mean_trajectory()


# ------------------------------------------------------------------------ conditioning
def _np_condition(mean, cov, psi, y, r):
    """Independent Gaussian conditioning of w ~ N(mean, cov) on psi w + eps = y, eps ~ N(0, r)."""
    s = psi @ cov @ psi.T + r
    k = cov @ psi.T @ np.linalg.inv(s)
    return mean + k @ (y - psi @ mean), cov - k @ psi @ cov


def test_condition_passes_through_via_point_and_reduces_variance(gen):
    promp = fitted(gen)
    t = 20
    z = promp.phase[t]
    target = torch.tensor([3.0, -2.0], dtype=F64)
    out = promp.condition(z, target, y_cov=1e-10)
    torch.testing.assert_close(out.mean_trajectory()[t], target, rtol=0, atol=1e-6)
    std_before, std_after = promp.std_trajectory(), out.std_trajectory()
    assert bool((std_after[t] < 1e-3).all()) and bool((std_before[t] > 0.1).all())
    assert bool((std_after <= std_before + 1e-9).all())  # conditioning never adds variance
    # the original is untouched (a new ProMP is returned)
    assert not torch.allclose(promp.mean_trajectory()[t], target)


def test_condition_matches_independent_gaussian_formula(gen):
    promp = fitted(gen, n=20, full_cov=True)
    z, y, r = 0.35, np.array([1.0, 0.5]), np.array([[0.01, 0.002], [0.002, 0.02]])
    out = promp.condition(z, torch.from_numpy(y), y_cov=torch.from_numpy(r))
    phi = promp.basis_at(torch.tensor([z], dtype=F64)).numpy()[0]  # (K,)
    k, d = promp.num_basis, promp.num_dof
    psi = np.zeros((d, d * k))
    for i in range(d):
        psi[i, i * k : (i + 1) * k] = phi
    mean, cov = _np_condition(promp.mean.numpy(), promp.cov.numpy(), psi, y, r)
    np.testing.assert_allclose(out.mean.numpy(), mean, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(out.cov.numpy(), 0.5 * (cov + cov.T), rtol=1e-8, atol=1e-8)


def test_condition_on_multiple_via_points(gen):
    promp = fitted(gen)
    idx = [0, 25, 49]
    targets = torch.tensor([[0.0, 1.0], [2.0, 2.0], [-1.0, 0.5]], dtype=F64)
    out = promp.condition(promp.phase[idx], targets, y_cov=1e-10)
    torch.testing.assert_close(out.mean_trajectory()[idx], targets, rtol=0, atol=1e-5)
    assert bool((out.std_trajectory()[idx] < 1e-3).all())
    # per-via-point covariances (V, D, D): a loose via point is hardly pulled
    y_cov = torch.stack([1e-10 * torch.eye(2), 1e-10 * torch.eye(2), 1e6 * torch.eye(2)]).to(F64)
    loose = promp.condition(promp.phase[idx], targets, y_cov=y_cov)
    torch.testing.assert_close(loose.mean_trajectory()[idx[:2]], targets[:2], rtol=0, atol=1e-5)
    assert (loose.mean_trajectory()[idx[2]] - targets[2]).abs().min() > 1e-3


def test_condition_one_dof_accepts_a_vector_of_via_points(gen):
    promp = make(num_dof=1)
    promp.fit(promp.trajectory(torch.randn(5, promp.num_weights, generator=gen, dtype=F64)))
    out = promp.condition(promp.phase[[10, 40]], torch.tensor([1.0, -1.0]), y_cov=1e-10)
    torch.testing.assert_close(
        out.mean_trajectory()[[10, 40], 0], torch.tensor([1.0, -1.0], dtype=F64), rtol=0, atol=1e-5
    )


def test_condition_bad_input_raises(gen):
    promp = fitted(gen)
    with pytest.raises(ValueError, match=r"phases must lie in \[0, 1\]"):
        promp.condition(1.5, torch.zeros(2))
    with pytest.raises(ValueError, match="2 via phase"):
        promp.condition([0.1, 0.2], torch.zeros(3, 2))
    with pytest.raises(ValueError, match="y contains NaN"):
        promp.condition(0.5, torch.tensor([0.0, float("nan")]))
    with pytest.raises(ValueError, match=r"y_cov must be a float, \(2, 2\)"):
        promp.condition(0.5, torch.zeros(2), y_cov=torch.eye(3))
    with pytest.raises(ValueError, match=r"y_cov must be a float"):
        promp.condition([0.2, 0.5], torch.zeros(2, 2), y_cov=torch.ones(3, 2, 2))
    with pytest.raises(ValueError, match="y_cov contains NaN"):
        promp.condition(0.5, torch.zeros(2), y_cov=float("nan"))
    with pytest.raises(ValueError, match="y_cov must be positive semi-definite"):
        promp.condition(0.5, torch.zeros(2), y_cov=-1.0)
    with pytest.raises(ValueError, match="y_cov must be positive semi-definite"):
        promp.condition(0.5, torch.zeros(2), y_cov=torch.tensor([[1.0, 2.0], [2.0, 1.0]]))
    # y of the wrong width is refused, not silently reshaped into other via points
    with pytest.raises(ValueError, match=r"y must be \(V, 2\) or \(2,\)"):
        promp.condition(0.5, torch.zeros(3))
    with pytest.raises(ValueError, match=r"y must be \(V, 2\) or \(2,\)"):
        promp.condition([0.1, 0.5, 0.9], torch.zeros(2, 3))
    with pytest.raises(RuntimeError, match="no weight distribution"):
        make().condition(0.5, torch.zeros(2))


# --------------------------------------------------------------- buffers and dtypes
def test_state_dict_round_trip_into_a_fresh_promp(gen):
    promp = fitted(gen, full_cov=True)
    fresh = make()
    assert not bool(fresh.fitted)
    fresh.load_state_dict(promp.state_dict())
    assert bool(fresh.fitted)
    for name in ("mean", "cov", "basis", "phase", "centers"):
        assert torch.equal(getattr(fresh, name), getattr(promp, name)), name
    torch.testing.assert_close(fresh.mean_trajectory(), promp.mean_trajectory(), rtol=0, atol=0)
    torch.testing.assert_close(fresh.std_trajectory(), promp.std_trajectory(), rtol=0, atol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fit_and_generate_in_dtype(gen, dtype):
    promp = make(dtype=dtype, ridge=1e-10 if dtype == F64 else 1e-6)
    w_true = torch.randn(4, promp.num_weights, generator=gen, dtype=F64)
    demos = promp.trajectory(w_true)
    assert demos.dtype == dtype and promp.basis.dtype == dtype
    promp.fit(demos)
    assert promp.mean.dtype == promp.cov.dtype == dtype
    assert (
        promp.sample(3).dtype
        == promp.mean_trajectory().dtype
        == promp.std_trajectory().dtype
        == dtype
    )
    atol = 1e-6 if dtype == F64 else 5e-3
    torch.testing.assert_close(promp.mean, w_true.mean(0).to(dtype), rtol=0, atol=atol)
    cond = promp.condition(0.5, torch.tensor([1.0, 1.0]), y_cov=1e-6)
    assert cond.mean.dtype == dtype


def test_to_dtype_converts_every_float_buffer(gen):
    promp = fitted(gen)
    small = promp.to(torch.float32)
    for name, buf in small.named_buffers():
        assert buf.dtype == (torch.bool if name == "fitted" else torch.float32), name
    assert bool(small.fitted)
    torch.testing.assert_close(
        small.mean_trajectory(), fitted(torch.Generator().manual_seed(0)).mean_trajectory().float()
    )


# ------------------------------------------------------------------------- bad input
def test_fit_single_demo_raises():
    promp = make()
    demo = torch.zeros(50, 2)
    with pytest.raises(ValueError, match="at least 2 demonstrations to estimate a variance, got 1"):
        promp.fit(demo[None])
    with pytest.raises(ValueError, match="at least 2 demonstrations"):
        promp.fit([demo])


@pytest.mark.parametrize(
    "bad, word", [(float("nan"), "NaN"), (float("inf"), "inf"), (-float("inf"), "inf")]
)
def test_fit_non_finite_demos_raise(bad, word):
    promp = make()
    demos = torch.zeros(3, 50, 2)
    demos[1, 10, 0] = bad
    with pytest.raises(ValueError, match=f"demos contains {word}"):
        promp.fit(demos)
    listed = [torch.zeros(40, 2), torch.zeros(60, 2)]
    listed[1][3, 1] = bad
    with pytest.raises(ValueError, match=rf"demos\[1\] contains {word}"):
        promp.fit(listed)


def test_fit_wrong_shapes_raise():
    promp = make()
    with pytest.raises(ValueError, match=r"demos\[0\] must be \(T_i, 2\)"):
        promp.fit(torch.zeros(3, 50, 3))
    with pytest.raises(ValueError, match=r"must be \(n, T, D\)"):
        promp.fit(torch.zeros(2, 3, 50, 2))
    with pytest.raises(ValueError, match="need at least 2"):
        promp.fit([torch.zeros(1, 2), torch.zeros(5, 2)])
    with pytest.raises(ValueError, match="demos is empty"):
        promp.fit([])
    with pytest.raises(ValueError, match=r"weights must be \(n, 12\)"):
        promp.fit_weights(torch.zeros(3, 11))


@pytest.mark.parametrize(
    "args, kw, message",
    [
        ((0, 5, 10), {}, "num_dof >= 1"),
        ((1, 1, 10), {}, "num_basis >= 2"),
        ((1, 5, 1), {}, "num_steps >= 2"),
        ((1, 5, 10), {"ridge": -1.0}, "ridge must be >= 0"),
        ((1, 5, 10), {"width": 0.0}, "width must be finite and > 0"),
    ],
)
def test_bad_constructor_arguments_raise(args, kw, message):
    with pytest.raises(ValueError, match=message):
        ProMP(*args, **kw)


# ---------------------------------------------------------------- the audit's bad inputs
@pytest.mark.parametrize(
    "kw, match",
    [
        ({"ridge": float("nan")}, "ridge"),
        ({"ridge": -1.0}, "ridge"),
        ({"ridge": float("inf")}, "ridge"),
        ({"num_basis": 2.7}, "num_basis"),
        ({"num_dof": 1.5}, "num_dof"),
        ({"num_steps": float("nan")}, "num_steps"),
        ({"width": float("nan")}, "width"),
    ],
)
def test_bad_constructor_settings_are_refused(kw, match):
    args = {"num_dof": 1, "num_basis": 5, **kw}
    with pytest.raises(ValueError, match=match):
        ProMP(args.pop("num_dof"), args.pop("num_basis"), **args)


def _fitted(var=1.0):
    return ProMP(1, 5).set_distribution(
        torch.zeros(5, dtype=torch.float64), var=torch.full((5,), var)
    )


@pytest.mark.parametrize("n", [-1, 2.5, float("nan"), True])
def test_sample_count_must_be_a_nonnegative_int(n):
    with pytest.raises(ValueError, match="num_samples"):
        _fitted().sample(n)


def test_sample_zero_is_empty():
    assert _fitted().sample(0).shape == (0, 5)


def test_condition_on_a_deterministic_prior_with_exact_observation_is_refused():
    with pytest.raises(ValueError, match="y_cov"):
        _fitted(0.0).condition(0.5, torch.ones(1), 0.0)
    # with some observation noise the result is the prior (nothing can move a zero covariance)
    out = _fitted(0.0).condition(0.5, torch.ones(1), 0.1)
    torch.testing.assert_close(out.mean, torch.zeros(5, dtype=torch.float64))


def test_condition_needs_at_least_one_via_point():
    with pytest.raises(ValueError, match="at least one via point"):
        _fitted().condition([], torch.zeros(0, 1))


def test_basis_at_gives_the_basis_and_its_phase_derivatives():
    """``basis_at(z, order=2)``: the basis and its first two phase derivatives (central finite
    differences), the same bits as the control code's derivative helpers; a bad order is refused."""
    from protorch.control.episodes import basis_derivative_at
    from protorch.control.policy_means import basis3

    p = ProMP(2, 8, 50).double()
    z = torch.linspace(0.05, 0.95, 19, dtype=F64)
    b = p.basis_at(z, order=2)  # (P, 3, K)
    assert b.shape == (19, 3, 8) and torch.equal(b[:, 0], p.basis_at(z))
    h = 1e-5
    fd1 = (p.basis_at(z + h) - p.basis_at(z - h)) / (2 * h)
    fd2 = (p.basis_at(z + h) - 2 * p.basis_at(z) + p.basis_at(z - h)) / h**2
    torch.testing.assert_close(b[:, 1], fd1, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(b[:, 2], fd2, rtol=1e-3, atol=1e-3)
    assert torch.equal(p.basis_at(z, order=1), b[:, :2])
    assert torch.equal(basis_derivative_at(p, z), b[:, 1]) and torch.equal(basis3(p, z), b)
    assert basis3(p, 0.35).shape == (3, 8) and torch.equal(basis3(p, z[7]), b[7])
    c, w = p.centers, p.width  # the closed form basis3 held before it called basis_at
    d = z[:, None] - c  # (P, K)
    g = torch.exp(-0.5 * (d / w) ** 2)
    g = g / g.sum(-1, keepdim=True)
    a = -d / w**2
    g1 = g * (a - (g * a).sum(-1, keepdim=True))
    g2 = g1 * (a - (g * a).sum(-1, keepdim=True)) - g * (g1 * a).sum(-1, keepdim=True)
    torch.testing.assert_close(basis3(p, z), torch.stack([g, g1, g2], -2), rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="order must be 0, 1 or 2"):
        p.basis_at(z, order=3)
