"""The point-particle experiment's pieces that follow the authors' scripts rather than protorch's
own choices: the moving test of ``main3.py`` (``dynamic_paper.*`` in ``metrics.json``, frames and
a GIF) and the authors' convergence rule with their quality thresholds
(``optimizer.convergence=authors``), and :func:`hole_failures`, why means fail under the
paper's literal hole objective (``hole_analysis.*`` with ``task.objectives=hole``).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..checks import check_int, check_keys
from ..control.paper_scenario import run_paper_episodes, sample_paper_envs
from ..figures.online import plot_episode_frames, write_episode_gif
from ..optim.convergence import AuthorsRule, make_rule
from ..tasks.point_particle import HOLE_HALF_HEIGHT, WALL_HALF_WIDTH, signed_distance_to_wall

__all__ = [
    "PAPER_SEED",
    "PAPER_KEYS",
    "paper_settings",
    "evaluate_paper",
    "paper_figures",
    "convergence_rule",
    "hole_failures",
]

PAPER_SEED = 3_000_029  # the authors' moving test: first environments (never a training seed)
PAPER_KEYS = {"episodes", "seed", "hold", "kp", "kd", "goal_tol", "start", "duration", "dt"}
# rwpo.py: mean start and end distance <= 0.005, best sample's clearance >= 0.1 (the clearance
# cost is 1 - min signed distance, so <= 0.9)
_START, _MIDDLE, _END = 0, 1, 2


def paper_settings(cfg: dict | None, *, training_seeds: tuple[int, ...]) -> dict:
    """Validated ``dynamic_paper`` settings: ``episodes`` (100), ``seed`` (:data:`PAPER_SEED`),
    plus :func:`~protorch.control.paper_scenario.run_paper_episodes` options."""
    cfg = dict(cfg or {})
    check_keys(cfg, PAPER_KEYS, "dynamic_paper")
    cfg["episodes"] = check_int(cfg.get("episodes", 100), "dynamic_paper.episodes", 0)
    seed = cfg.get("seed", PAPER_SEED)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed in training_seeds:
        raise ValueError(
            f"dynamic_paper.seed must be an integer other than the training seeds "
            f"{list(training_seeds)}, got {seed!r}"
        )
    cfg["seed"] = int(seed)
    return cfg


def evaluate_paper(
    task, model, cfg: dict, *, dtype=torch.float64, device="cpu"
) -> tuple[dict, object]:
    """``(metrics, episodes)`` of the authors' moving test for a map (an EnvToProMP)."""
    cfg = dict(cfg)
    n, seed = cfg.pop("episodes"), cfg.pop("seed")
    if n == 0:
        return {"episodes": 0, "success_rate": float("nan")}, None
    env0 = sample_paper_envs(task, n, torch.Generator().manual_seed(seed), dtype=dtype).to(device)
    res = run_paper_episodes(model, task, env0, **cfg)
    return {**res.summary(), "seed": seed, "collisions": int(res.collided.sum())}, res


def paper_figures(out_dir: Path, episodes, index: int = 0) -> None:
    """``online_paper_frames.png`` and ``online_paper_episode.gif``: episode ``index``."""
    if episodes is None:
        return
    ep = episodes.episode(index)
    kw = {k: ep[k] for k in ("positions", "envs", "means", "markers")}
    title = "the authors' test: start fixed; wall, hole and goal moving at 10 units/s"
    plot_episode_frames(
        Path(out_dir) / "online_paper_frames.png",
        **kw,
        dt=ep["dt"],
        success=ep["success"],
        title=title,
    )
    write_episode_gif(
        Path(out_dir) / "online_paper_episode.gif",
        **kw,
        dt=ep["dt"],
        success=ep["success"],
        title=title,
    )


def convergence_rule(kwargs: dict, objectives: str) -> dict:
    """Optimiser keyword arguments with ``convergence="authors"`` replaced by the authors' rule
    and the point particle's thresholds (the clearance one only with the clearance objective);
    any other setting is returned as it is."""
    if kwargs.get("convergence", "mean") != "authors":
        make_rule(
            kwargs.get("convergence", "mean"),
            tol=float(kwargs.get("tol", 1e-3)),
            window=int(kwargs.get("window", 5)),
        )  # refuses a bad name now
        # the default rule is the optimiser's default: leave it out (the loop's signature unchanged)
        return {k: v for k, v in kwargs.items() if not (k == "convergence" and v == "mean")}
    best = {_MIDDLE: 0.9} if objectives == "clearance" else {}
    rule = AuthorsRule(
        float(kwargs.get("tol", 1e-3)),
        int(kwargs.get("window", 5)),
        mean_at_most={_START: 0.005, _END: 0.005},
        best_at_most=best,
    )
    return {**kwargs, "convergence": rule}


def hole_failures(
    task, traj, env, *, corner: float = 0.5, through: float = 0.1, substeps: int = 10
) -> dict:
    """Why means fail under the paper's hole objective: ``traj (Q, T, 2)``, ``env (Q, d)``.

    Counts the collisions, those whose path passes within ``through`` of the hole's centre (the
    objective is then met), and those whose points inside the wall (the path resampled
    ``substeps`` times per step) all lie within ``corner`` (Chebyshev) of one of the hole's four
    corners ``(wall_x -+ 1, hole_y -+ 1)``: the path cuts a corner of the 2-unit-thick wall."""
    env6 = task.full_env(env)  # (Q, 6)
    with torch.no_grad():
        collided = task.collides(traj, env)  # (Q,)
        centre = env6[:, None, 2:4]  # (Q, 1, 2)
        to_centre = (traj - centre).norm(dim=-1).amin(-1)  # (Q,)
        u = torch.linspace(0, 1, substeps + 1, dtype=traj.dtype, device=traj.device)[:-1]  # (U,)
        a, b = traj[:, :-1, None], traj[:, 1:, None]  # (Q, T-1, 1, 2)
        pts = (a + u[:, None] * (b - a)).flatten(1, 2)  # (Q, (T-1) U, 2)
        pts = torch.cat([pts, traj[:, -1:]], 1)  # (Q, M, 2)
        inside = (
            signed_distance_to_wall(pts, env6[:, None], infinite_wall=task.infinite_wall) < 0
        )  # (Q, M)
        sx = torch.tensor([-1.0, 1.0], dtype=traj.dtype, device=traj.device)
        corners = torch.stack(
            torch.broadcast_tensors(
                env6[:, 2, None, None] + sx[:, None] * WALL_HALF_WIDTH,
                env6[:, 3, None, None] + sx[None, :] * HOLE_HALF_HEIGHT,
            ),
            -1,
        ).flatten(1, 2)  # (Q, 4, 2)
        cheb = (pts[:, :, None] - corners[:, None]).abs().amax(-1).amin(-1)  # (Q, M)
        at_corner = inside.any(-1) & ~(inside & (cheb > corner)).any(-1)  # (Q,)
    c = collided
    return {
        "means": int(traj.shape[0]),
        "collisions": int(c.sum()),
        "collisions_through_centre": int((c & (to_centre <= through)).sum()),
        "collisions_at_corners_only": int((c & at_corner).sum()),
        "centre_distance_median_of_collisions": float(to_centre[c].median())
        if bool(c.any())
        else float("nan"),
    }
