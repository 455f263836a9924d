"""Fig. 3 of the paper: PRO keeps the variance of a weight that does not matter, RWR does not.

A 2-D Gaussian over ``(w1, w2)`` is optimised for ``R = exp(-beta d)`` with ``d`` the distance to
the line ``w2 = offset``; ``w1`` is irrelevant. The "weights" are the points themselves.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from ..figures.paper import plot_cloud, plot_curves, save_figure
from ..optim import PRO, RWR
from ..tasks import LineToy
from .common import optimizer_kwargs

__all__ = ["run"]


def run(
    out_dir: Path,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    dtype: torch.dtype = torch.float64,
    init_mean=(0.0, 0.0),
    init_std=(1.0, 1.0),
    offset: float = 2.0,
    optimizer: dict,
    eval_samples: int = 10_000,
    plot: bool = True,
) -> dict:
    """Run PRO and RWR from the same Gaussian; return the metrics (and write the figure)."""
    task = LineToy(offset=offset)
    mean = torch.tensor(init_mean, dtype=dtype, device=device)
    std = torch.tensor(init_std, dtype=dtype, device=device)
    if mean.shape != (2,) or std.shape != (2,):
        raise ValueError(
            f"init_mean and init_std must have 2 entries, got {list(init_mean)} and "
            f"{list(init_std)}"
        )
    if bool((std <= 0).any()):
        raise ValueError(f"init_std must be > 0, got {list(init_std)}")
    common = dict(optimizer, tol=0.0)  # the figure runs the full budget
    results, seconds, finals = {}, {}, {}
    gen = torch.Generator(device=device).manual_seed(seed + 1)
    for name, cls in (("pro", PRO), ("rwr", RWR)):
        kwargs = optimizer_kwargs(common, optimizer.get(name))
        opt = cls(mean, std**2, seed=seed, **kwargs)
        t0 = time.perf_counter()
        results[name] = opt.minimize(task.costs)
        seconds[name] = time.perf_counter() - t0
        res = results[name]
        w = res.mean + res.var.sqrt() * torch.randn(
            eval_samples, 2, generator=gen, dtype=dtype, device=device
        )
        finals[name] = w
    beta = float(optimizer["beta"])
    finals["initial"] = mean + std * torch.randn(
        eval_samples, 2, generator=gen, dtype=dtype, device=device
    )
    metrics = {"initial_std": std.tolist()}
    for name, res in results.items():
        w = finals[name]  # (eval_samples, 2)
        metrics[name] = {
            "final_std": res.var.sqrt().tolist(),
            "final_mean": res.mean.tolist(),
            # expected reward E[exp(-beta d)] under the final distribution
            "final_reward": float(torch.exp(-beta * task.costs(w)).mean()),
            "iterations": res.iterations,
            "seconds": seconds[name],
        }
    metrics["pro"]["irrelevant_std_ratio"] = (
        metrics["pro"]["final_std"][0] / metrics["initial_std"][0]
    )
    metrics["rwr"]["irrelevant_std_ratio"] = (
        metrics["rwr"]["final_std"][0] / metrics["initial_std"][0]
    )
    if plot:
        _figure(Path(out_dir) / "fig3_toy.png", task, results, finals, beta, std)
    return metrics


def _figure(path, task, results, finals, beta, std) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    ax = axes[0]
    w0 = finals["initial"][:2000]
    plot_cloud(ax, w0, label="initial", color="0.7", alpha=0.2)
    plot_cloud(ax, finals["pro"][:2000], label="PRO", color="tab:blue")
    plot_cloud(ax, finals["rwr"][:2000], label="RWR", color="tab:red", alpha=0.8)
    line = task.line()
    ax.plot(line[:, 0], line[:, 1], "k--", lw=1, label="d = 0")
    ax.set_xlabel("w1 (irrelevant)")
    ax.set_ylabel("w2")
    ax.set_title("initial and final samples")
    ax.legend(fontsize=7)
    curves = {}
    for name, res in results.items():
        s = res.history["var"].sqrt()  # (I, 2)
        curves[f"{name.upper()} std w1"] = s[:, 0] / std[0]
        curves[f"{name.upper()} std w2"] = s[:, 1] / std[1]
    plot_curves(axes[1], curves, ylabel="std / initial std", logy=True)
    rewards = {
        f"{n.upper()}": torch.exp(-beta * r.history["cost"][:, 0]) for n, r in results.items()
    }
    plot_curves(axes[2], rewards, ylabel="exp(-beta * mean sample cost)")
    save_figure(fig, path)
