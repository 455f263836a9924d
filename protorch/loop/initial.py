"""The loop's initial data set: one weight Gaussian per demonstrated environment (and label)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from ..data.dataset import TrajectoryDataset

__all__ = ["demonstration_dataset", "group_by_env"]


def group_by_env(envs: Tensor) -> list[Tensor]:
    """Indices of the rows of ``envs (n, E)`` grouped by identical environment, in order of first
    appearance: a list of ``(n_g,)`` long tensors."""
    uniq, inverse = torch.unique(envs, dim=0, return_inverse=True)  # (G, E), (n,)
    first = torch.full((uniq.shape[0],), envs.shape[0], dtype=torch.long)
    first = first.scatter_reduce(0, inverse, torch.arange(envs.shape[0]), reduce="amin")  # (G,)
    order = torch.argsort(first)
    return [torch.nonzero(inverse == g).flatten() for g in order.tolist()]


def demonstration_dataset(
    promp,
    demos: Sequence[Tensor],
    demo_envs: Tensor,
    *,
    task_name: str = "",
    var_floor: float = 0.0,
    dtype: torch.dtype = torch.float64,
    labels: Tensor | None = None,
    lone: str = "refuse",
) -> TrajectoryDataset:
    """One entry per demonstrated environment (and label): the maximum-likelihood diagonal weight
    Gaussian of its demonstrations (``origin="demonstration"``, ``converged=True``).

    Args:
        promp: the :class:`~protorch.ProMP` whose basis the weights use.
        demos: ``n`` trajectories ``(T_i, D)``.
        demo_envs: ``(n, E)``, row ``i`` the environment of ``demos[i]``; rows that are equal
            form one environment (each needs at least 2 demonstrations for a variance).
        var_floor: lower bound on every variance (the GP noise of the entry), so a weight on
            which the demonstrations agree exactly still has a positive noise.
        labels: ``(n,)`` integer class of each demonstration (e.g. the side it passes an
            obstacle on); demonstrations of one environment with different labels form
            separate entries, never averaged. ``None``: every entry has label 0.
        lone: an environment (and label) with 1 demonstration: ``"refuse"`` (an error), or
            ``"pool"``: its variance is the mean variance of the same label's entries with >= 2
            demonstrations (an error where that label has none).

    Example: two environments, three straight 2-D demonstrations each.

    >>> from protorch import ProMP
    >>> promp = ProMP(num_dof=2, num_basis=5, num_steps=20)
    >>> envs = torch.tensor([[0.0], [0.0], [0.0], [1.0], [1.0], [1.0]])  # (6, E=1)
    >>> s = torch.linspace(0, 1, 20)[:, None]  # (T, 1)
    >>> demos = [s * torch.tensor([1.0, 0.1 * i]) + e for i, e in enumerate(envs)]  # (T, 2) each
    >>> data = demonstration_dataset(promp, demos, envs, var_floor=1e-4)
    >>> data.env.shape, data.mean.shape, bool((data.var >= 1e-4).all())
    (torch.Size([2, 1]), torch.Size([2, 10]), True)
    """
    demo_envs = torch.as_tensor(demo_envs)
    if demo_envs.ndim != 2 or demo_envs.shape[0] != len(demos):
        raise ValueError(f"demo_envs must be ({len(demos)}, E), got {tuple(demo_envs.shape)}")
    if not var_floor >= 0:
        raise ValueError(f"var_floor must be >= 0, got {var_floor}")
    lab = (
        torch.zeros(len(demos), dtype=torch.long)
        if labels is None
        else torch.as_tensor(labels).cpu()
    )
    if lab.shape != (len(demos),) or lab.is_floating_point() or lab.dtype == torch.bool:
        raise ValueError(f"labels must be ({len(demos)},) integers, got {labels!r}")
    w = promp.weights(demos).to(dtype).cpu()  # (n, N)
    demo_envs = demo_envs.cpu()
    ds = TrajectoryDataset(promp, demo_envs.shape[1], task_name=task_name, dtype=dtype)
    keyed = (
        demo_envs if labels is None else torch.cat([demo_envs.to(dtype), lab[:, None].to(dtype)], 1)
    )
    if lone not in ("refuse", "pool"):
        raise ValueError(f"lone must be 'refuse' or 'pool', got {lone!r}")
    groups = group_by_env(keyed)
    var = {}
    for g, idx in enumerate(groups):
        if idx.numel() >= 2:
            wg = w[idx]  # (n_g, N)
            var[g] = (wg - wg.mean(0)).pow(2).mean(0).clamp_min(var_floor)  # (N,)
        elif lone == "refuse":
            raise ValueError(
                f"environment {demo_envs[idx[0]].tolist()} (label {int(lab[idx[0]])}) has 1 "
                "demonstration; "
                "a weight variance needs >= 2"
            )
    measured = dict(var)
    for g, idx in enumerate(groups):
        if g not in var:  # a lone demonstration: the mean variance of its label's other entries
            same = [v for h, v in measured.items() if int(lab[groups[h][0]]) == int(lab[idx[0]])]
            if not same:
                raise ValueError(
                    f"environment {demo_envs[idx[0]].tolist()} (label {int(lab[idx[0]])}) has 1 "
                    "demonstration and no environment has >= 2 of that label to pool a variance "
                    "from"
                )
            var[g] = torch.stack(same).mean(0)  # (N,)
        ds.append(
            demo_envs[idx[0]].to(dtype),
            w[idx].mean(0),
            var[g],
            label=int(lab[idx[0]]),
            origin="demonstration",
            converged=True,
        )
    return ds


def dataset_pool(dataset: TrajectoryDataset, num_envs: int, dtype) -> Tensor:
    """The first ``num_envs`` distinct environments of the data set, in order: ``(num_envs, E)``
    (``choice="dataset"``: the paper's arm loop iterates its initialisation environments)."""
    env = dataset.env.to(dtype).cpu()  # (M, E)
    first = (
        torch.stack([g[0] for g in group_by_env(env)])
        if env.shape[0]
        else torch.zeros(0, dtype=torch.long)
    )
    if first.numel() < num_envs:
        raise ValueError(
            f"choice='dataset' needs num_envs <= the data set's {first.numel()} distinct "
            f"environments, got num_envs={num_envs}"
        )
    return env[first[:num_envs]]
