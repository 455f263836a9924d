"""Backend ``"gpytorch"``: a batch of ``N`` independent GPyTorch ``ExactGP``s per label group.

``batch_shape = [N]``, ``FixedNoiseGaussianLikelihood`` with the per-environment variances as
noise (no learned noise), an RBF kernel fixed to ``exp(-alpha ||.||^2)`` (inputs are scaled by
``sqrt(2 alpha)`` so the lengthscale is exactly 1, no output scale), a ``ConstantMean`` set to the
average training mean; nothing is trained. Exactness at every size is enforced around every
prediction:

* ``max_cholesky_size`` is raised above any data size (GPyTorch otherwise switches to CG /
  Lanczos above 800 points) and ``fast_computations`` is off;
* ``min_fixed_noise`` is 0 (GPyTorch otherwise floors noise at 1e-6 in float64 / 1e-4 in float32);
* ``add`` appends to the training data, sets the new constant mean and noise, and drops the
  prediction strategy (GPyTorch caches ``A^-1 (y - m)``, which goes stale when the mean changes).
  The exact solve is redone at the next prediction: this backend has no incremental update, the
  ``"torch"`` backend has.

``approx_var=True`` uses LOVE (``fast_pred_var`` with a Lanczos root of rank
``love_rank``); its error is printed by ``benchmarks/gp.py``. If Cholesky fails (duplicates with
near-zero variances), GPyTorch's own jitter retry applies.
"""

from __future__ import annotations

import math
import warnings
from contextlib import ExitStack
from typing import cast

import gpytorch
import torch
from torch import Tensor, nn

from .base import EnvMap

__all__ = ["GPyTorchEnvMap", "exact_settings"]

_HUGE = 2**31 - 1


def exact_settings() -> ExitStack:
    """A context in which GPyTorch computes exact Cholesky-based posteriors with the given noise."""
    stack = ExitStack()
    stack.enter_context(gpytorch.settings.max_cholesky_size(_HUGE))
    stack.enter_context(
        gpytorch.settings.min_fixed_noise(float_value=0.0, double_value=0.0, half_value=0.0)
    )
    stack.enter_context(gpytorch.settings.fast_computations(False, False, False))
    stack.enter_context(gpytorch.settings.debug(False))
    return stack


class _BatchExactGP(gpytorch.models.ExactGP):
    def __init__(self, x: Tensor, y: Tensor, noise: Tensor, const: Tensor) -> None:
        batch = torch.Size(y.shape[:-1])  # (N,) or (Q, N)
        with exact_settings():  # GPyTorch floors the fixed noise when the likelihood is built
            lik = gpytorch.likelihoods.FixedNoiseGaussianLikelihood(noise=noise, batch_shape=batch)
        super().__init__(x, y, lik)
        self.mean_module = gpytorch.means.ConstantMean(batch_shape=batch)
        self.covar_module = gpytorch.kernels.RBFKernel(batch_shape=batch)
        self.to(x)  # parameters in the data's dtype before setting them (float32 would round)
        self.covar_module.lengthscale = torch.ones_like(self.covar_module.lengthscale)
        self.mean_module.constant = const
        self.eval()
        self.likelihood.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def forward(self, x: Tensor):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class GPyTorchEnvMap(EnvMap):
    """GPyTorch backend (module docstring). Extra option ``love_rank``: Lanczos rank of LOVE.

    Example: fit ``M = 6`` environments ``(M, d)`` with their weight means and variances
    ``(M, N)``, predict at two

    >>> g = torch.Generator().manual_seed(0)
    >>> E, MU = torch.rand(6, 2, generator=g), torch.rand(6, 4, generator=g)
    >>> env_map = GPyTorchEnvMap(alpha=1.0).fit(E, MU, torch.full((6, 4), 0.1))
    >>> mu, var = env_map.predict(E[:2])  # (Q, N) each
    >>> mu.shape, bool((var > 0).all())
    (torch.Size([2, 4]), True)
    """

    backend = "gpytorch"

    def __init__(
        self,
        alpha: float,
        *,
        nearest_k: int | None = None,
        love_rank: int = 100,
        dtype: torch.dtype = torch.float64,
        device=None,
    ) -> None:
        super().__init__(alpha, nearest_k=nearest_k, dtype=dtype, device=device)
        if isinstance(love_rank, bool) or int(love_rank) != love_rank or int(love_rank) < 1:
            raise ValueError(f"love_rank must be an int >= 1, got {love_rank!r}")
        self.love_rank = int(love_rank)
        self.models = nn.ModuleDict()
        self._scale = math.sqrt(2.0 * self.alpha)  # exp(-alpha r^2) = exp(-0.5 (scale r)^2)

    def options(self) -> dict:
        return {**super().options(), "love_rank": self.love_rank}

    def _reset_groups(self) -> None:
        self.models = nn.ModuleDict()

    def _has_group(self, g: int) -> bool:
        return str(g) in self.models

    def _train_data(self, g: int):
        sel = self.labels == g
        E, MU, VAR = self.E[sel], self.MU[sel], self.VAR[sel]  # (Mg, d), (Mg, N), (Mg, N)
        n = MU.shape[1]
        x = (E * self._scale).expand(n, *E.shape).contiguous()  # (N, Mg, d)
        return x, MU.T.contiguous(), VAR.T.contiguous(), MU.mean(0), VAR.mean(0)

    def _group_fit(self, g, E, MU, VAR) -> None:
        x, y, noise, mu0, _ = self._train_data(g)
        self.models[str(g)] = _BatchExactGP(x, y, noise, mu0)

    def _group_add(self, g, E, MU, VAR) -> None:
        # The base class already stored the new rows: take the whole group again.
        x, y, noise, mu0, _ = self._train_data(g)
        model = cast(_BatchExactGP, self.models[str(g)])
        model.set_train_data(inputs=x, targets=y, strict=False)
        with exact_settings():
            model.likelihood.noise = noise
        model.mean_module.constant = mu0
        model.prediction_strategy = None  # stale A^-1 (y - m) and LOVE caches

    def _group_predict(self, g, Eq, *, need_var, approx_var):
        model = self.models[str(g)]
        sel = self.labels == g
        vbar = self.VAR[sel].mean(0)  # (N,)
        n = vbar.shape[0]
        xq = (Eq * self._scale).expand(n, *Eq.shape)  # (N, Q, d)
        with (
            torch.no_grad(),
            exact_settings(),
            gpytorch.settings.fast_pred_var(False),
            gpytorch.settings.skip_posterior_variances(not need_var or approx_var),
        ):
            post = model(xq)
            mu = post.mean.T  # (Q, N), the mean cache is now an exact Cholesky solve
            var = post.variance.T if need_var and not approx_var else None  # (Q, N)
        if need_var and approx_var:
            # LOVE: force the Lanczos root (below max_cholesky_size GPyTorch would use an exact,
            # full-size root, which is no faster); the exact mean cache above is kept.
            with (
                torch.no_grad(),
                warnings.catch_warnings(),
                gpytorch.settings.debug(False),
                gpytorch.settings.fast_pred_var(True),
                gpytorch.settings.max_cholesky_size(0),
                gpytorch.settings.min_fixed_noise(
                    float_value=0.0, double_value=0.0, half_value=0.0
                ),
                gpytorch.settings.max_root_decomposition_size(self.love_rank),
            ):
                warnings.simplefilter("ignore")
                var = model(xq).variance.T  # (Q, N)
        return mu, var.clamp_min(0) + vbar if var is not None else None

    def _predict_subsets(self, Es, MUs, VARs, Eq, *, need_var):
        q, k, n = MUs.shape
        x = (Es * self._scale)[:, None].expand(q, n, k, Es.shape[-1]).contiguous()  # (Q, N, k, d)
        y = MUs.transpose(1, 2).contiguous()  # (Q, N, k)
        noise = VARs.transpose(1, 2).contiguous()  # (Q, N, k)
        model = _BatchExactGP(x, y, noise, MUs.mean(1))
        xq = (Eq * self._scale)[:, None, None].expand(q, n, 1, Eq.shape[-1])  # (Q, N, 1, d)
        with (
            torch.no_grad(),
            exact_settings(),
            gpytorch.settings.fast_pred_var(False),
            gpytorch.settings.skip_posterior_variances(not need_var),
        ):
            post = model(xq)
            mu = post.mean[..., 0]  # (Q, N)
            var = post.variance[..., 0].clamp_min(0) + VARs.mean(1) if need_var else None  # (Q, N)
        return mu, var
