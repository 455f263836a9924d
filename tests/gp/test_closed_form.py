"""The torch backend on degenerate data: duplicates added with zero variance, and conflicting
near-duplicates whose exact solve amplifies round-off (the audit's cases)."""

from __future__ import annotations

import warnings

import pytest
import torch

from protorch.gp import make_env_map
from protorch.gp.base import EnvMapWarning


@pytest.mark.parametrize("offset", [0.0, 1e-8])
def test_add_of_a_known_environment_with_zero_variance_is_finite(offset):
    E = torch.rand(1, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    z = torch.zeros(1, 20, dtype=torch.float64)
    gp = make_env_map("torch", alpha=1e-2).fit(E, z, z)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnvMapWarning)
        gp.add(E + offset, z + 1, z)
    mu, var = gp.predict(E)
    assert bool(torch.isfinite(mu).all()) and bool(torch.isfinite(var).all())
    # the same rows fitted at once: two conflicting exact observations average to 0.5
    ref = make_env_map("torch", alpha=1e-2).fit(
        torch.cat([E, E + offset]), torch.cat([z, z + 1]), torch.cat([z, z])
    )
    torch.testing.assert_close(mu, ref.predict(E)[0], atol=1e-3, rtol=0)
    torch.testing.assert_close(mu, torch.full_like(mu, 0.5), atol=1e-3, rtol=0)


def _conflicting(seed=1):
    g = torch.Generator().manual_seed(seed)
    E = torch.rand(20, 3, generator=g, dtype=torch.float64) * 4
    MU = torch.randn(20, 5, generator=g, dtype=torch.float64)
    E2 = torch.cat([E, E + 1e-7 * torch.randn(20, 3, generator=g, dtype=torch.float64)])
    MU2 = torch.cat([MU, MU + torch.randn(20, 5, generator=g, dtype=torch.float64)])
    Q = torch.rand(200, 3, generator=g, dtype=torch.float64) * 4
    return E2, MU2, torch.zeros_like(MU2), Q


@pytest.mark.parametrize("step", ["fit", "add"])
def test_conflicting_near_duplicates_warn_with_the_bound(step):
    """With zero noise, near-duplicates of conflicting means make ``A^-1 (MU - mu0)`` huge: the
    mean at a query is then far outside the data. ``|mu(e) - mu0| <= sum_i |coef_i|`` (k <= 1),
    and the backend warns whenever that bound exceeds the data's range by far."""
    E, MU, VAR, Q = _conflicting()
    gp = make_env_map("torch", alpha=1.0)
    with pytest.warns(EnvMapWarning, match="outside the data"):
        if step == "fit":
            gp.fit(E, MU, VAR)
        else:
            gp.fit(E[:20], MU[:20], VAR[:20])
            gp.add(E[20:], MU[20:], VAR[20:])
    mu = gp.predict(Q)[0]
    grp = gp.groups["0"]
    bound = grp.coef[: grp.m].abs().sum(0)  # (N,)
    assert bool(((mu - grp.mu0).abs() <= bound * (1 + 1e-9)).all())  # the bound holds
    assert float((mu - grp.mu0).abs().max()) > 10 * float(
        (MU - MU.mean(0)).abs().max()
    )  # and is real


def test_consistent_data_does_not_warn():
    E, MU, VAR, Q = _conflicting()
    with warnings.catch_warnings():
        warnings.simplefilter("error", EnvMapWarning)
        gp = make_env_map("torch", alpha=1.0).fit(E[:20], MU[:20], VAR[:20] + 1e-2)
        gp.add(E[20:], MU[:20] + 1e-9, VAR[20:] + 1e-2)
