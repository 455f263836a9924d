"""Probabilistic Movement Primitives (Paraschos et al. 2013) as a torch module.

A trajectory of ``D`` degrees of freedom over ``T`` steps is ``tau = Phi w`` with ``Phi`` the
``(T, K)`` matrix of ``K`` normalised Gaussian basis functions on the phase ``z in [0, 1]``, one
block per DoF, so ``w`` has ``N = D * K`` entries laid out DoF-major: ``w[d * K + k]``.

Every tensor is a buffer, so ``.to(device, dtype)`` and ``state_dict`` carry the basis and the
fitted distribution. Shapes are given in the comments: ``n`` demonstrations, ``S`` samples.
"""

from __future__ import annotations

import copy
from typing import Any, Sequence

import torch
from torch import Tensor, nn

from ..checks import check_int, check_number, check_positive, check_tensor
from ..threads import one_thread

__all__ = ["ProMP", "gaussian_basis", "resample"]


def gaussian_basis(phase: Tensor, centers: Tensor, width: float, order: int = 0) -> Tensor:
    """Normalised Gaussian basis ``(len(phase), K)``: rows sum to one. With ``order`` 1 or 2, the
    basis and its first ``order`` phase derivatives, ``(len(phase), order + 1, K)``: with
    ``b_k = exp(-(z - c_k)^2 / (2 w^2))``, ``g_k = b_k / sum_j b_j``, ``a_k = -(z - c_k) / w^2``
    and ``s = sum_j g_j a_j``: ``g' = g (a - s)``, ``g'' = g' (a - s) - g sum_j g'_j a_j``.

    >>> gaussian_basis(torch.tensor([0.0, 0.5]), torch.linspace(0, 1, 3), 0.3, order=2).shape
    torch.Size([2, 3, 3])
    """
    if order not in (0, 1, 2):
        raise ValueError(f"order must be 0, 1 or 2, got {order!r}")
    d = phase[:, None] - centers[None, :]  # (T, K)
    b = torch.exp(-0.5 * (d / width) ** 2)  # (T, K)
    g = b / b.sum(-1, keepdim=True)  # (T, K)
    if order == 0:
        return g
    a = -d / width**2  # (T, K)
    s = (g * a).sum(-1, keepdim=True)  # (T, 1)
    out = [g, g * (a - s)]
    if order == 2:
        out.append(out[1] * (a - s) - g * (out[1] * a).sum(-1, keepdim=True))
    return torch.stack(out, -2)  # (T, order + 1, K)


def resample(y: Tensor, num_steps: int) -> Tensor:
    """Linearly resample a trajectory ``(T_i, D)`` to ``(num_steps, D)`` over a common phase."""
    t_in = y.shape[0]
    if t_in == num_steps:
        return y
    pos = torch.linspace(0, t_in - 1, num_steps, dtype=y.dtype, device=y.device)  # (T,)
    lo = pos.floor().long().clamp(max=t_in - 1)
    hi = (lo + 1).clamp(max=t_in - 1)
    frac = (pos - lo.to(y.dtype))[:, None]  # (T, 1)
    return y[lo] * (1 - frac) + y[hi] * frac  # (T, D)


def _roundoff(x: Tensor) -> float:
    """Round-off tolerance of a covariance-like tensor: 1000 ulps of its largest entry."""
    return 1e3 * torch.finfo(x.dtype).eps * max(float(x.abs().max()) if x.numel() else 0.0, 1e-30)


def demo_list(demos: Tensor | Sequence[Tensor], shapes: str) -> Sequence[Tensor]:
    """``demos`` as a sequence of demonstrations: a tensor ``(n, T, ...)`` (or one demonstration
    ``(T, ...)``) split along its first axis, a sequence as given (not empty). ``shapes`` names
    the shapes allowed in the error (:meth:`ProMP.fit`,
    :meth:`~protorch.primitives.pose.PoseProMP.fit`)."""
    if isinstance(demos, Tensor):
        demos = check_tensor(demos, "demos")
        if demos.ndim == 2:
            demos = demos[None]
        if demos.ndim != 3:
            raise ValueError(f"demos must be {shapes} {tuple(demos.shape)}")
        demos = list(demos)
    if len(demos) == 0:
        raise ValueError("demos is empty")
    return demos


class ProMP(nn.Module):
    """A ProMP: basis functions plus a Gaussian over weights ``N(mean, cov)``.

    Args:
        num_dof: ``D``, degrees of freedom of a trajectory.
        num_basis: ``K``, basis functions per DoF (the authors used 10).
        num_steps: ``T``, time steps of a generated trajectory.
        width: standard deviation of each Gaussian basis in phase units; default the spacing
            between centres, ``1 / (K - 1)``.
        ridge: ``lambda`` of the ridge fit ``w = (Phi^T Phi + lambda I)^-1 Phi^T y``.
        dtype, device: of the buffers (float64 by default).

    Example: fit three demonstrations of 40 steps, generate the mean trajectory on ``T = 50``

    >>> t = torch.linspace(0, 1, 40, dtype=torch.float64)
    >>> demos = [torch.stack([t, t**2 + 0.01 * k], -1) for k in range(3)]  # (40, D = 2) each
    >>> promp = ProMP(num_dof=2, num_basis=5, num_steps=50).fit(demos)
    >>> promp.mean.shape, promp.trajectory(promp.mean).shape  # (N = D K,), (T, D)
    (torch.Size([10]), torch.Size([50, 2]))
    >>> promp.basis_at(0.5, order=2).shape  # the basis and two phase derivatives at z = 0.5
    torch.Size([1, 3, 5])
    """

    # the registered buffers (typed for the type checker; nn.Module.__getattr__ returns them)
    phase: Tensor  # (T,)
    centers: Tensor  # (K,)
    basis: Tensor  # (T, K)
    mean: Tensor  # (N,)
    cov: Tensor  # (N, N)
    fitted: Tensor  # () bool

    def __init__(
        self,
        num_dof: int,
        num_basis: int = 10,
        num_steps: int = 100,
        *,
        width: float | None = None,
        ridge: float = 1e-11,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        sizes = ((num_dof, "num_dof", 1), (num_basis, "num_basis", 2), (num_steps, "num_steps", 2))
        if any(isinstance(v, (int, float)) and v < lo for v, _, lo in sizes):
            raise ValueError(
                f"need num_dof >= 1, num_basis >= 2, num_steps >= 2; "
                f"got {num_dof}, {num_basis}, {num_steps}"
            )
        self.num_dof, self.num_basis, self.num_steps = (
            check_int(v, name, lo) for v, name, lo in sizes
        )
        ridge = check_number(ridge, "ridge", allow_zero=True)  # finite, >= 0
        self.width = float(width) if width is not None else 1.0 / (self.num_basis - 1)
        check_positive(self.width, "width")
        self.ridge = float(ridge)
        kw: dict[str, Any] = dict(dtype=dtype, device=device)
        n = self.num_weights
        self.register_buffer("phase", torch.linspace(0, 1, self.num_steps, **kw))  # (T,)
        self.register_buffer("centers", torch.linspace(0, 1, self.num_basis, **kw))  # (K,)
        self.register_buffer(
            "basis", gaussian_basis(self.phase, self.centers, self.width)
        )  # (T, K)
        self.register_buffer("mean", torch.zeros(n, **kw))  # (N,)
        self.register_buffer("cov", torch.zeros(n, n, **kw))  # (N, N)
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool, device=device))

    # ------------------------------------------------------------------ sizes
    @property
    def num_weights(self) -> int:
        """``N = D * K``."""
        return self.num_dof * self.num_basis

    @property
    def var(self) -> Tensor:
        """Diagonal of the weight covariance ``(N,)``."""
        return self.cov.diagonal()

    def extra_repr(self) -> str:
        return (
            f"num_dof={self.num_dof}, num_basis={self.num_basis}, num_steps={self.num_steps}, "
            f"width={self.width:.4g}, ridge={self.ridge:g}"
        )

    # ------------------------------------------------------------ fitting
    def _stack_demos(self, demos: Tensor | Sequence[Tensor]) -> Tensor:
        """Demonstrations of any lengths -> ``(n, T, D)`` on the common phase."""
        demos = demo_list(demos, "(n, T, D) or a list of (T_i, D), got")
        out = []
        for i, y in enumerate(demos):
            y = check_tensor(y, f"demos[{i}]").to(self.basis)
            if y.ndim == 1 and self.num_dof == 1:
                y = y[:, None]
            if y.ndim != 2 or y.shape[1] != self.num_dof:
                raise ValueError(
                    f"demos[{i}] must be (T_i, {self.num_dof}) for a {self.num_dof}-DoF ProMP, "
                    f"got shape {tuple(y.shape)}"
                )
            if y.shape[0] < 2:
                raise ValueError(f"demos[{i}] has {y.shape[0]} time step(s); need at least 2")
            out.append(resample(y, self.num_steps))
        return torch.stack(out)  # (n, T, D)

    def weights(self, demos: Tensor | Sequence[Tensor]) -> Tensor:
        """Ridge-regression weights of each demonstration: ``(n, N)``. The products and the
        solve run on one torch thread: the same bits at any thread count."""
        y = self._stack_demos(demos)  # (n, T, D)
        phi = self.basis  # (T, K)
        with (
            one_thread()
        ):  # MKL (under the app's MKL_CBWR) gave other bits on 2 threads, 60 to 4,000 demos
            gram = phi.T @ phi + self.ridge * torch.eye(
                self.num_basis, dtype=phi.dtype, device=phi.device
            )
            rhs = torch.einsum("tk,ntd->nkd", phi, y)  # (n, K, D)
            w = torch.linalg.solve(gram, rhs)  # (n, K, D)
        return w.transpose(-1, -2).reshape(y.shape[0], self.num_weights)  # (n, N)

    def fit(
        self, demos: Tensor | Sequence[Tensor], *, full_cov: bool = False, min_var: float = 0.0
    ) -> "ProMP":
        """Maximum-likelihood Gaussian over the demonstrations' weights (diagonal by default)."""
        return self.fit_weights(self.weights(demos), full_cov=full_cov, min_var=min_var)

    def fit_weights(self, w: Tensor, *, full_cov: bool = False, min_var: float = 0.0) -> "ProMP":
        """Maximum-likelihood Gaussian over given weights ``(n, N)``; needs ``n >= 2``."""
        w = check_tensor(w, "weights", ndim=2).to(self.basis)
        if w.shape[1] != self.num_weights:
            raise ValueError(f"weights must be (n, {self.num_weights}), got {tuple(w.shape)}")
        if w.shape[0] < 2:
            raise ValueError(
                f"fitting a weight distribution needs at least 2 demonstrations to estimate a "
                f"variance, got {w.shape[0]}"
            )
        mean = w.mean(0)  # (N,)
        dw = w - mean  # (n, N)
        if full_cov:
            cov = dw.T @ dw / w.shape[0]  # (N, N), maximum likelihood (biased)
        else:
            cov = torch.diag((dw**2).mean(0))  # (N, N)
        if min_var > 0:
            cov = cov + min_var * torch.eye(self.num_weights, dtype=cov.dtype, device=cov.device)
        return self.set_distribution(mean, cov=cov)

    def set_distribution(
        self, mean: Tensor, var: Tensor | None = None, cov: Tensor | None = None
    ) -> "ProMP":
        """Set the weight Gaussian from ``mean (N,)`` and ``var (N,)`` or ``cov (N, N)``."""
        mean = check_tensor(mean, "mean", ndim=1).to(self.basis)
        if mean.shape[0] != self.num_weights:
            raise ValueError(f"mean must be ({self.num_weights},), got {tuple(mean.shape)}")
        if (var is None) == (cov is None):
            raise ValueError("give exactly one of var or cov")
        if var is not None:
            var = check_tensor(var, "var", ndim=1).to(self.basis)
            if var.shape != mean.shape:
                raise ValueError(f"var must be ({self.num_weights},), got {tuple(var.shape)}")
            if bool((var < 0).any()):
                raise ValueError("var must be >= 0")
            cov = torch.diag(var)
        else:
            cov = check_tensor(cov, "cov", ndim=2).to(self.basis)
            if cov.shape != (self.num_weights, self.num_weights):
                raise ValueError(
                    f"cov must be ({self.num_weights}, {self.num_weights}), got {tuple(cov.shape)}"
                )
            tol = _roundoff(cov)
            if float((cov - cov.T).abs().max()) > tol:
                raise ValueError("cov must be symmetric")
            if bool((torch.diagonal(cov) < -tol).any()):
                raise ValueError(
                    f"cov must have variances >= 0 on its diagonal, got a minimum of "
                    f"{float(torch.diagonal(cov).min()):.3g}"
                )
        self.mean.copy_(mean)
        self.cov.copy_(0.5 * (cov + cov.T))
        self.fitted.fill_(True)
        return self

    # --------------------------------------------------------- generating
    def basis_at(self, phase: Tensor | float, order: int = 0) -> Tensor:
        """Basis evaluated at arbitrary phases ``(P,)`` (or a float) -> ``(P, K)``; with ``order``
        1 or 2 the basis and its first ``order`` phase derivatives ``d^i Phi / dz^i``,
        ``(P, order + 1, K)`` (:func:`gaussian_basis`), in the ProMP's dtype."""
        phase = torch.as_tensor(phase, dtype=self.basis.dtype, device=self.basis.device).reshape(-1)
        return gaussian_basis(phase, self.centers, self.width, order)

    def trajectory(
        self, w: Tensor, phase: Tensor | None = None, *, basis: Tensor | None = None
    ) -> Tensor:
        """Weights ``(..., N)`` -> trajectories ``(..., T, D)`` (or ``(..., P, D)`` at ``phase``;
        ``basis``: :meth:`basis_at` ``phase`` where the caller keeps it). The product runs on one
        torch thread: the same bits at any thread count."""
        if w.shape[-1] != self.num_weights:
            raise ValueError(
                f"w must end in {self.num_weights} weights, got shape {tuple(w.shape)}"
            )
        phi = (
            basis if basis is not None else self.basis if phase is None else self.basis_at(phase)
        )  # (T, K)
        w = w.to(phi.dtype).unflatten(-1, (self.num_dof, self.num_basis))  # (..., D, K)
        with one_thread():  # MKL's product (under the app's MKL_CBWR) gives other bits on 2 threads
            return torch.einsum("tk,...dk->...td", phi, w)  # (..., T, D)

    def _require_fitted(self) -> None:
        if not bool(self.fitted):
            raise RuntimeError(
                "the ProMP has no weight distribution yet: call fit() or set_distribution()"
            )

    def sample(self, num_samples: int, *, generator: torch.Generator | None = None) -> Tensor:
        """Draw weights ``(S, N)`` from the weight Gaussian."""
        num_samples = check_int(num_samples, "num_samples", 0)
        self._require_fitted()
        n = self.num_weights
        z = torch.randn(
            num_samples, n, generator=generator, dtype=self.mean.dtype, device=self.mean.device
        )
        off_diag = self.cov - torch.diag(self.var)
        if bool((off_diag != 0).any()):
            eye = torch.eye(n, dtype=self.cov.dtype, device=self.cov.device)
            scale = self.cov.diagonal().mean().clamp_min(1e-30)
            chol, info = torch.linalg.cholesky_ex(self.cov + 1e-10 * scale * eye)
            if int(info) != 0:  # not positive definite: use the symmetric square root
                evals, evecs = torch.linalg.eigh(self.cov)
                chol = evecs * evals.clamp_min(0).sqrt()
            return self.mean + z @ chol.T  # (S, N)
        return self.mean + z * self.var.sqrt()  # (S, N)

    def mean_trajectory(self) -> Tensor:
        """``(T, D)``."""
        self._require_fitted()
        return self.trajectory(self.mean)

    def std_trajectory(self) -> Tensor:
        """Marginal standard deviation of each position ``(T, D)``, from the full covariance."""
        self._require_fitted()
        k, d = self.num_basis, self.num_dof
        blocks = self.cov.reshape(d, k, d, k).diagonal(dim1=0, dim2=2).permute(2, 0, 1)  # (D, K, K)
        var = torch.einsum("tk,dkl,tl->td", self.basis, blocks, self.basis)  # (T, D)
        return var.clamp_min(0).sqrt()

    # -------------------------------------------------------- conditioning
    def condition(self, phase, y: Tensor, y_cov: Tensor | float = 0.0) -> "ProMP":
        """A new ProMP conditioned to pass through via points.

        Args:
            phase: ``(V,)`` phases in [0, 1] (or a float for one via point).
            y: ``(V, D)`` desired positions (or ``(D,)``).
            y_cov: observation covariance: a float (isotropic), ``(D, D)`` shared by every via
                point, or ``(V, D, D)``.
        """
        self._require_fitted()
        phase = torch.as_tensor(phase, dtype=self.basis.dtype, device=self.basis.device).reshape(-1)
        if bool(((phase < 0) | (phase > 1)).any()):
            raise ValueError(f"via-point phases must lie in [0, 1], got {phase.tolist()}")
        v, d = phase.shape[0], self.num_dof
        if v == 0:
            raise ValueError("condition() needs at least one via point, got an empty phase")
        y = check_tensor(torch.as_tensor(y), "y").to(self.basis)
        if y.ndim == 1:  # (D,) for one via point, or (V,) for a 1-DoF ProMP
            y = y[:, None] if d == 1 else y[None]
        if y.ndim != 2 or y.shape[1] != d:
            raise ValueError(
                f"y must be (V, {d}) or ({d},) for a {d}-DoF ProMP, got shape {tuple(y.shape)}"
            )
        if y.shape[0] != v:
            raise ValueError(f"{v} via phase(s) but y has {y.shape[0]} row(s) of {d} DoF")
        y_cov = torch.as_tensor(y_cov, dtype=self.basis.dtype, device=self.basis.device)
        eye_d = torch.eye(d, dtype=self.basis.dtype, device=self.basis.device)
        if y_cov.ndim == 0:
            y_cov = (y_cov * eye_d).expand(v, d, d)
        elif y_cov.ndim == 2 and y_cov.shape == (d, d):
            y_cov = y_cov.expand(v, d, d)
        if y_cov.shape != (v, d, d):
            raise ValueError(
                f"y_cov must be a float, ({d}, {d}) or ({v}, {d}, {d}), got {tuple(y_cov.shape)}"
            )
        check_tensor(y_cov, "y_cov")
        sym = 0.5 * (y_cov + y_cov.transpose(-1, -2))  # (V, D, D)
        if float(torch.linalg.eigvalsh(sym).min()) < -_roundoff(y_cov):
            raise ValueError(
                "y_cov must be positive semi-definite (a covariance of the via points)"
            )
        # Psi maps weights to the V*D observed positions: (V*D, N), block-diagonal per DoF.
        phi = self.basis_at(phase)  # (V, K)
        psi = torch.einsum("vk,de->vdek", phi, eye_d).reshape(v * d, self.num_weights)  # (V*D, N)
        obs_cov = torch.block_diag(*y_cov)  # (V*D, V*D)
        sig = self.cov  # (N, N)
        s = psi @ sig @ psi.T + obs_cov  # (V*D, V*D)
        sol, info = torch.linalg.solve_ex(s, psi @ sig)  # (V*D, N)
        if int(info) != 0 or not bool(torch.isfinite(sol).all()):
            raise ValueError(
                "the via points' covariance Psi Sigma Psi^T + y_cov is singular (the ProMP's "
                "covariance is zero at those phases and y_cov is 0): give y_cov > 0"
            )
        gain = sol.T  # (N, V*D)
        new_mean = self.mean + gain @ (y.reshape(-1) - psi @ self.mean)  # (N,)
        new_cov = sig - gain @ psi @ sig  # (N, N)
        out = copy.deepcopy(self)
        return out.set_distribution(new_mean, cov=new_cov)
