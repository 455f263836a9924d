"""How close the large-data maps come to the exact map (Eq. 7, 8 on all data), and at what cost.

Methods, each against the exact closed-form map (``torch`` backend) on the same data:

* ``sparse k=K``: protorch's sparse backend without ``nearest_k`` (the label's prior mean and
  average variance, the solve on the K nearest environments), K = 16, 32, 64, 128;
* ``authors k=30``: the sparse backend with ``nearest_k=30`` (the authors' local GPs: the 30
  nearest and their own prior mean), what the arm experiment runs;
* ``SGPR r=R``: GPyTorch's SGPR (``InducingPointKernel``, R inducing points drawn from the
  data, the per-weight noise of Eq. 8 as ``FixedNoiseGaussianLikelihood``, nothing trained), a
  batch over the weights.

Errors over every query and weight: the mean's error in units of the weight's spread over the data
(``std_m MU[m, n]``; median, 99th percentile, max) and in units of its prior std
(``sqrt(k(e, e) + vbar_n)``, max); the variance's error relative to the exact variance (median,
p99, max) and in units of the prior variance (max). Time: build plus 200 queries (mean + variance).

Data: ``arm-like`` (4-D environments on a 0.6 m table, alpha = 30, smooth weights, as
``benchmarks/gp_scaling.py``), ``particle-like`` (6-D in [0, 10]^6, alpha = 1e-3), and with
``--runs DIR ...`` the data sets of finished runs (``protorch.load``: their alpha and labels),
200 random entries held out as queries.

    python benchmarks/gp_sparse.py [--sizes 1000,2000,4000] [--weights 8] [--runs runs/arm ...]
"""

from __future__ import annotations

import argparse
import time

import gpytorch
import torch
from gp_scaling import smooth_data  # noqa: E402  (benchmarks/ is the script's directory)

from protorch import load
from protorch.gp import make_env_map
from protorch.gp.gpytorch_exact import exact_settings

QUERIES = 200


class SGPR(gpytorch.models.ExactGP):
    """``N`` SGPR models as one batch: shared inducing points ``(R, d)``, per-weight fixed noise."""

    def __init__(self, x, y, noise, inducing, const):
        batch = torch.Size(y.shape[:-1])  # (N,)
        with exact_settings():
            lik = gpytorch.likelihoods.FixedNoiseGaussianLikelihood(noise=noise, batch_shape=batch)
        super().__init__(x, y, lik)
        self.mean_module = gpytorch.means.ConstantMean(batch_shape=batch)
        base = gpytorch.kernels.RBFKernel(batch_shape=batch)
        self.covar_module = gpytorch.kernels.InducingPointKernel(base, inducing, lik)
        self.to(x)
        base.lengthscale = torch.ones_like(base.lengthscale)
        self.mean_module.constant = const
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


def sgpr_predict(E, MU, VAR, Eq, alpha, r, seed=0):
    """SGPR (module docstring) fitted on one label's data, predicting ``Eq``: ``(mu, var)``."""
    scale = (2 * alpha) ** 0.5  # exp(-alpha d^2) = RBF with lengthscale 1 on scaled inputs
    n = MU.shape[1]
    pick = torch.randperm(E.shape[0], generator=torch.Generator().manual_seed(seed))[:r]
    x = (E * scale).expand(n, *E.shape).contiguous()  # (N, M, d)
    model = SGPR(x, MU.T.contiguous(), VAR.T.contiguous(), (E[pick] * scale).clone(), MU.mean(0))
    xq = (Eq * scale).expand(n, *Eq.shape)  # (N, Q, d)
    with torch.no_grad(), exact_settings(), gpytorch.settings.fast_pred_var(False):
        post = model(xq)
        return post.mean.T, post.variance.T + VAR.mean(0)  # (Q, N)


def datasets(args):
    """``(name, E, MU, VAR, labels, Eq, qlabels, alpha)`` per data source."""
    out = []
    g = torch.Generator().manual_seed(5)
    for m in (int(s) for s in args.sizes.split(",")):
        E, MU, VAR = smooth_data(m + QUERIES, args.weights)
        out.append((f"arm-like M={m}", E[:m], MU[:m], VAR[:m], None, E[m:], None, 30.0))
        E, MU, VAR = smooth_data(m + QUERIES, args.weights, d=6, side=10.0, seed=1)
        MU = MU + 0.3 * (
            E @ torch.randn(6, args.weights, generator=g, dtype=torch.float64)
        )  # broad trends
        out.append((f"particle-like M={m}", E[:m], MU[:m], VAR[:m], None, E[m:], None, 1e-3))
    for run in args.runs:
        em = load(run).env_map
        keep = (
            torch.linspace(0, em.num_weights - 1, min(args.weights, em.num_weights)).round().long()
        )
        perm = torch.randperm(em.num_points, generator=torch.Generator().manual_seed(0))
        q, r = perm[:QUERIES], perm[QUERIES:].sort().values
        out.append(
            (
                f"{run} M={r.numel()}",
                em.E[r],
                em.MU[r][:, keep],
                em.VAR[r][:, keep],
                em.labels[r],
                em.E[q],
                em.labels[q],
                em.alpha,
            )
        )
    return out


def errors(mu, var, ref_mu, ref_var, VAR, MU) -> list[list[float]]:
    """``[[mean / spread: median, p99, max], [mean / prior std: max], [var relative: median, p99,
    max], [var / prior var: max]]`` over every query and weight."""
    prior_var = 1.0 + VAR.mean(0)  # (N,) k(e, e) + vbar
    em = (mu - ref_mu).abs()  # (Q, N)
    ev = (var - ref_var).abs()  # (Q, N)
    q = torch.tensor([0.5, 0.99], dtype=em.dtype)

    def stats(x):
        return [*torch.quantile(x.flatten(), q).tolist(), float(x.max())]

    return [
        stats(em / MU.std(0)),
        [float((em / prior_var.sqrt()).max())],
        stats(ev / ref_var),
        [float((ev / prior_var).max())],
    ]


def per_label(predict, E, MU, VAR, labels, Eq, qlabels):
    """``predict(E, MU, VAR, Eq)`` applied per label (methods without label support)."""
    if labels is None:
        return predict(E, MU, VAR, Eq)
    mu = torch.empty(Eq.shape[0], MU.shape[1], dtype=MU.dtype)
    var = torch.empty_like(mu)
    for g in qlabels.unique().tolist():
        s, sq = labels == g, qlabels == g
        mu[sq], var[sq] = predict(E[s], MU[s], VAR[s], Eq[sq])
    return mu, var


def methods(alpha):
    def map_method(**opts):
        def predict(E, MU, VAR, Eq):
            return make_env_map("sparse", alpha, **opts).fit(E, MU, VAR).predict(Eq)

        return predict

    out = {f"sparse k={k}": map_method(neighbours=k) for k in (16, 32, 64, 128)}
    out["authors k=30"] = map_method(nearest_k=30)
    for r in (128, 512):
        out[f"SGPR r={r}"] = lambda E, MU, VAR, Eq, r=r: sgpr_predict(E, MU, VAR, Eq, alpha, r)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,4000")
    ap.add_argument("--weights", type=int, default=8, help="weights compared (a subset of a run's)")
    ap.add_argument("--runs", nargs="*", default=[])
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(
        "| data | method | mean error / spread: median, p99, max | mean error / prior std: max "
        "| variance rel. error: median, p99, max | variance error / prior var: max | build + 200 "
        "queries (s) |\n"
        "|---|---|---|---|---|---|---|"
    )
    for name, E, MU, VAR, lab, Eq, qlab, alpha in datasets(args):
        t = time.perf_counter()
        ref = make_env_map("torch", alpha).fit(E, MU, VAR, lab).predict(Eq, qlab)
        print(f"| {name} | exact (torch) | | | | | {time.perf_counter() - t:.2f} |", flush=True)
        for mname, fn in methods(alpha).items():
            t = time.perf_counter()
            mu, var = per_label(fn, E, MU, VAR, lab, Eq, qlab)
            dt = time.perf_counter() - t
            cols = " | ".join(
                ", ".join(f"{x:.2g}" for x in c) for c in errors(mu, var, *ref, VAR, MU)
            )
            print(f"| {name} | {mname} | {cols} | {dt:.2f} |", flush=True)


if __name__ == "__main__":
    main()
