"""Fig. 4 of the paper: the 2-D window task, PRO against the older RWPO.

Five imperfect demonstrations become a ProMP (10 weights per DoF); both optimisers improve it on
three objectives (start, window centre as a minimum over time, end). The paper's point is the
cost of the relevance: one Pearson correlation (PRO) against an iterative search (RWPO).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import torch

from ..figures.paper import plot_relevance, plot_trajectories, plot_window, save_figure
from ..optim import PRO, RWPO
from ..primitives.promp import ProMP
from ..tasks import WindowTask
from .common import optimizer_kwargs

__all__ = ["run"]


def run(
    out_dir: Path,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    dtype: torch.dtype = torch.float64,
    task: dict | None = None,
    num_demos: int = 5,
    promp: dict | None = None,
    optimizer: dict,
    plot: bool = True,
) -> dict:
    task_obj = WindowTask(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in (task or {}).items()}
    )
    gen = torch.Generator().manual_seed(seed)
    demos = task_obj.demonstrations(num_demos, generator=gen, dtype=dtype)
    model = ProMP(2, **(promp or {}), dtype=dtype, device=device).fit([d.to(device) for d in demos])

    def objective(w):  # (B, S, N) -> (B, S, 3)
        return task_obj.costs(model.trajectory(w))

    metrics: dict = {"demos": {"count": num_demos}}
    demo_w = model.weights([d.to(device) for d in demos])  # (n, N)
    metrics["demos"]["mean_trajectory"] = _distances(task_obj, model.mean_trajectory())
    metrics["demos"]["success_rate"] = float(
        task_obj.success(model.trajectory(demo_w)).double().mean()
    )
    results, opts = {}, {}
    for name, cls in (("pro", PRO), ("rwpo", RWPO)):
        kwargs = optimizer_kwargs(optimizer, optimizer.get(name))
        if cls is RWPO:
            kwargs.update(num_objectives=task_obj.num_objectives, num_basis=model.num_basis)
        opt = cls(model.mean, model.var, seed=seed, **kwargs)
        t0 = time.perf_counter()
        res = opt.minimize(objective)
        seconds = time.perf_counter() - t0
        results[name], opts[name] = res, opt
        mean_traj = model.trajectory(res.mean)
        metrics[name] = {
            **_distances(task_obj, mean_traj),
            "success": bool(task_obj.success(mean_traj)),
            # one relevance computation, rollouts included (median over the iterations for PRO)
            "relevance_seconds": statistics.median(res.relevance_seconds),
            "relevance_computations": len(res.relevance_seconds),
            "iterations": res.iterations,
            "converged": bool(res.converged),
            "seconds": seconds,
            "relevance": opt.relevance[0].tolist(),
        }
    metrics["relevance_speedup"] = (
        metrics["rwpo"]["relevance_seconds"] / metrics["pro"]["relevance_seconds"]
    )
    if plot:
        _figure(Path(out_dir) / "fig4_window.png", task_obj, model, demos, results, opts)
    return metrics


def _distances(task: WindowTask, traj: torch.Tensor) -> dict:
    c = task.costs(traj)
    return {name: float(v) for name, v in zip(task.objective_names, c)}


def _figure(path, task, model, demos, results, opts) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(18, 4.2))
    ax = axes[0]
    plot_window(ax, task)
    for d in demos:
        plot_trajectories(ax, d, color="0.5", lw=1)
    plot_trajectories(ax, model.mean_trajectory(), color="k", lw=2, label="demonstrations' mean")
    ax.set_title("demonstrations")
    ax.legend(
        fontsize=7, loc="upper left"
    )  # a free corner: the paths run lower left to upper right
    colors = {"pro": "tab:blue", "rwpo": "tab:orange"}
    ax = axes[1]
    plot_window(ax, task)
    gen = torch.Generator(device=model.mean.device).manual_seed(0)
    for name, res in results.items():
        samples = res.mean + res.var.sqrt() * torch.randn(
            20, res.mean.shape[-1], generator=gen, dtype=res.mean.dtype, device=res.mean.device
        )
        plot_trajectories(ax, model.trajectory(samples), color=colors[name], lw=0.5, alpha=0.4)
        plot_trajectories(
            ax, model.trajectory(res.mean), color=colors[name], lw=2, label=name.upper()
        )
    ax.set_title("solutions (mean and samples)")
    ax.legend(
        fontsize=7, loc="upper left"
    )  # a free corner: the paths run lower left to upper right
    k = model.num_basis
    for ax, name in zip(axes[2:], ("pro", "rwpo")):
        first = results[name].history["relevance"][0]  # relevance at the first iteration (O, N)
        t = results[name].relevance_seconds
        # the paper's Fig. 4 (c, d): the K weights of the x coordinate, (O, K)
        plot_relevance(
            ax,
            first[:, :k],
            task.objective_names,
            xlabel="x weight index (basis function)",
            title=f"{name.upper()} relevance (first iteration), {t[0]:.3g} s",
            legend_loc="below",
        )
    save_figure(fig, path)
