"""Sec. IV-B of the paper: a point particle passes the hole of a thick wall (the README's main job).

1. Demonstrations: 30 environments x 3 (synthetic, or the authors' human demonstrations from a
   folder), one ProMP weight Gaussian per environment.
2. The self-improvement loop (:func:`protorch.loop.self_improve`) with PRO over 1000 random
   environments, ``B`` at a time; the data set is checkpointed in ``<out_dir>/checkpoint``
   (``protorch.load(out_dir)`` gives the trained map) and can be resumed.
3. Evaluation of the map's mean trajectories on 200 held-out random environments (a fixed seed
   of their own) and on 100 moving-environment episodes
   (:func:`protorch.control.particle.run_episodes`,
   the paper's Fig. 6 test), for the trained map and for two baselines in the same run: the GP
   on the demonstrations only, and the same loop with RWR in place of PRO
   (``<out_dir>/baselines/rwr``).
4. Figures: success rate vs loop iteration, a grid of test environments with sampled and mean
   trajectories, Fig. 6-style frames of one moving episode and an animated GIF of it.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..checks import check_int
from ..control.particle import run_episodes
from ..data.demos import PARTICLE_FORMAT, check_demo_groups, read_demo_folder, read_marks
from ..data.recordings import Cleaning
from ..figures.common import legend_below
from ..figures.online import plot_episode_frames, write_episode_gif
from ..figures.paper import plot_point_particle, plot_trajectories, save_figure
from ..tasks import PointParticleTask
from .common import baseline_spec, demo_source, optimizer_label
from .loop_run import (
    DEMO_SEED_OFFSET,
    DYNAMIC_SEED,
    TEST_SEED,
    Outcome,
    SelfImprovementExperiment,
    experiment_functions,
)
from .particle_paper import (
    convergence_rule,
    evaluate_paper,
    hole_failures,
    paper_figures,
    paper_settings,
)

__all__ = ["run", "prepare", "Setup", "PointParticleExperiment", "TEST_SEED", "DYNAMIC_SEED"]

_BASELINES = ("demos_only", "rwr")


class PointParticleExperiment(SelfImprovementExperiment):
    """The point-particle parts of the skeleton (:class:`SelfImprovementExperiment`): the task and
    its demonstrations, the authors' ``stop_when_solved`` margins, the RWR loop baseline, the
    moving hole and goal, the figures. ``benchmarks/loop.py`` times :meth:`run_loop` at other
    batch sizes."""

    task_keys = frozenset(
        {
            "_target_",
            "objectives",
            "fixed_start",
            "infinite_wall",
            "demos",
            "demo_envs",
            "demos_per_env",
            "recordings",
        }
    )
    loop_keys = frozenset({"stop_when_solved"})
    dynamic_keys = frozenset(
        {"seed", "episodes", "duration", "hold", "dt", "kp", "kd", "step_std", "start", "goal_tol"}
    )
    gp_defaults = {"alpha": 1e-3, "var_floor": 1e-4, "nearest_k": None}
    num_envs = 1000
    baseline_names = _BASELINES
    pre_loop_baselines = frozenset({"demos_only"})
    loop_baselines = frozenset({"rwr"})

    def __init__(
        self,
        *,
        baseline_optimizer: dict | None = None,
        dynamic_paper: dict | None = None,
        **settings,
    ):
        self.baseline_optimizer = baseline_optimizer
        self.dynamic_paper = dynamic_paper
        self.paper_episodes = None
        super().__init__(**settings)

    def configure(self, task_cfg: dict, loop_cfg: dict) -> None:
        self.task = PointParticleTask(
            **{
                k: (tuple(v) if isinstance(v, list) else v)
                for k, v in task_cfg.items()
                if k in ("objectives", "fixed_start", "infinite_wall")
            }
        )
        self.source = demo_source(task_cfg.get("demos", "synthetic"))
        self.cleaning = Cleaning.from_config(task_cfg.get("recordings"))
        self.demo_envs_n = check_int(task_cfg.get("demo_envs", 30), "task.demo_envs", 1)
        self.per_env = check_int(task_cfg.get("demos_per_env", 3), "task.demos_per_env", 2)
        if self.source != "synthetic" and self.task.fixed_start is not None:
            raise ValueError(
                "the human demonstrations have 6-D environments: leave task.fixed_start unset"
            )
        self.stop_when_solved = loop_cfg.get("stop_when_solved", False)
        seed = int(self.seed)
        self.paper_cfg = paper_settings(
            self.dynamic_paper, training_seeds=(seed, seed + DEMO_SEED_OFFSET)
        )
        self.optimizers = {
            m: (cls, convergence_rule(kw, self.task.objectives))
            for m, (cls, kw) in (
                ("pro", self.optimizer),
                ("rwr", baseline_spec(self.optimizer_cfg, self.baseline_optimizer)),
            )
        }

    def num_dof(self) -> int:
        return 2

    def make_demonstrations(self) -> None:
        """Synthetic, or the folder ``task.demos`` (every environment with >= 2 demonstrations)."""
        self.demo_marked = 0
        if self.source == "synthetic":
            self.demos, self.demo_envs = self.task.demonstrations(
                self.demo_envs_n, self.per_env, self.demo_generator()
            )
            return
        folder, _ = read_demo_folder(self.source, PARTICLE_FORMAT, self.cleaning)
        check_demo_groups(folder.envs, folder.files)
        self.demos, self.demo_envs, self.demo_marked = (
            folder.demos,
            folder.envs,
            len(read_marks(self.source)),
        )

    def loop_options(self) -> dict:
        point = self.task

        def solved(traj, env):  # the authors' acceptance margins, looser on the end points
            return point.success(traj, env, tol=0.05) & (point.clearance(traj, env) >= 0.1)

        return {"solved": solved if self.stop_when_solved else None}

    def loop_arguments(self, variant: str | None) -> dict:
        """The method's optimiser, or ``variant="rwr"``: the ``baseline_optimizer`` (RWR by
        default)."""
        cls, kwargs = self.optimizers["pro" if variant is None else variant]
        return {"optimizer": cls, "optimizer_kwargs": kwargs, "dataset": self.initial_data()}

    def describe(self) -> dict:
        lk = self.loop
        return {
            "demos": {
                "source": str(self.source),
                "count": len(self.demos),
                "envs": len(self.initial_data()),
                "marked": self.demo_marked,
            },
            "settings": {
                "num_envs": lk.num_envs,
                "batch_size": lk.batch_size,
                "add_only": lk.add_only,
                "choice": lk.choice,
                "alpha": self.alpha,
                "beta": None
                if self.optimizer_cfg.get("beta") is None
                else float(self.optimizer_cfg["beta"]),
                "var_floor": self.var_floor,
                "objectives": self.task.objectives,
                **self.optimizer_names(),
            },
        }

    def optimizer_names(self) -> dict:
        """The registry names of the loop's optimiser and of the `rwr` baseline's (what the summary
        and the figures call the two loops): PRO and RWR unless the config names others."""
        return {
            "optimizer": self.optimizer_cfg.get("name", "pro"),
            "baseline_optimizer": (self.baseline_optimizer or {}).get("name", "rwr"),
        }

    def test_metrics(self, model) -> dict:
        """Success of the map's mean trajectories on the held-out environments."""
        task, envs = self.task, self.test_envs
        with torch.no_grad():
            traj = model.mean_trajectory(envs)  # (Q, T, 2)
            ok = task.success(traj, envs)  # (Q,)
            c = task.costs(traj, envs)  # (Q, 3)
        return {
            "success_rate": float(ok.double().mean()),
            "num_envs": int(envs.shape[0]),
            "seed": self.test_seed,
            "collision_rate": float(task.collides(traj, envs).double().mean()),
            "start_error_median": float(c[:, 0].median()),
            "goal_error_median": float(c[:, 2].median()),
        }

    def moving_test(self, model) -> tuple[dict, object]:
        """The moving hole and goal (:func:`protorch.control.particle.run_episodes`)."""
        if self.dyn_env0.shape[0] == 0:
            return {"success_rate": float("nan"), "episodes": 0}, None
        res = run_episodes(
            model,
            self.task,
            self.dyn_env0,
            generator=torch.Generator().manual_seed(self.dyn_seed),
            **self.dyn_cfg,
        )
        return {**res.summary(), "seed": self.dyn_seed}, res

    def extra_tests(self, model) -> dict:
        """The authors' moving test (``dynamic_paper``; :mod:`protorch.experiments.particle_paper`),
        and under the paper's hole objective why the held-out means fail (``hole_analysis``)."""
        out = {}
        out["dynamic_paper"], self.paper_episodes = evaluate_paper(
            self.task, model, self.paper_cfg, dtype=self.dtype, device=self.device
        )
        if self.task.objectives == "hole":
            out["hole_analysis"] = hole_failures(
                self.task, model.mean_trajectory(self.test_envs), self.test_envs
            )
        return out

    def figures(self, out_dir: Path, outcome: Outcome, metrics: dict) -> None:
        names = self.optimizer_names()
        loops = (
            (f"{optimizer_label(names['optimizer'])} loop", outcome.result, "tab:blue"),
            (
                f"{optimizer_label(names['baseline_optimizer'])} loop",
                outcome.baselines.get("rwr"),
                "tab:red",
            ),
        )
        _figures(
            out_dir,
            self.task,
            outcome.model,
            self.test_envs,
            loops,
            metrics,
            outcome.episodes,
            self.seed,
        )
        paper_figures(out_dir, self.paper_episodes)


Setup = PointParticleExperiment  # what prepare() returns


_RUN_DOC = """Run the experiment into ``out_dir``; return the metrics (see the module docstring).

    ``task``: ``objectives`` ("clearance" / "hole"), ``fixed_start``, ``infinite_wall``,
    ``demos`` ("synthetic" or a folder of ``trajK.out`` / ``envK.out``), ``demo_envs`` and
    ``demos_per_env`` (synthetic only). ``gp``: ``backend``, ``alpha``, ``var_floor``,
    ``nearest_k``. ``loop``: ``num_envs``, ``batch_size``, ``add_only``, ``choice``,
    ``checkpoint_every``, ``eval_dtype``, ``min_var``, ``stop_when_solved`` (see
    :func:`~protorch.loop.self_improve`). ``test``: ``num_envs``, ``seed``. ``dynamic``:
    ``episodes`` plus :func:`~protorch.control.particle.run_episodes` options. ``dynamic_paper``:
    the authors' moving test (start fixed; wall, hole and goal moving as ``main3.py`` moves
    them; :mod:`protorch.experiments.particle_paper`): ``episodes``, ``seed`` and
    :func:`~protorch.control.paper_scenario.run_paper_episodes` options. ``baselines``: any of
    ``demos_only``, ``rwr`` (the loop with ``baseline_optimizer``, an optimizer group; RWR by
    default). ``optimizer``: an optimizer group (``{"name": "pro", ...}``) or PRO's settings with
    per-method sections; ``optimizer.convergence``: ``mean`` (protorch's rule) or ``authors``.
    ``resume``: continue the loops from the checkpoints in ``out_dir``.
    Every setting is validated before any work starts.
    """
prepare, run = experiment_functions(
    PointParticleExperiment, baselines=_BASELINES, progress=True, run_doc=_RUN_DOC
)


# ----------------------------------------------------------------------------- figures
def _figures(out_dir, task, model, test_envs, loops, metrics, episode, seed) -> None:
    """Success vs loop iteration (``loops``: ``(name, LoopResult or None, colour)`` of the method's
    loop
    and the `rwr` baseline's), a grid of test environments, failures first, one moving episode
    (frames, GIF)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # success rate vs loop iteration, on the held-out environments
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, res, color in loops:
        if res is None:
            continue
        x = [r["envs_done"] for r in res.metrics]
        y = [r["eval_success"] for r in res.metrics]
        ax.plot(x, y, "-o", ms=3, color=color, label=f"{name}: held-out test")
        xs = [r["envs_done"] for r in res.metrics[1:]]
        ys = [r["initial_success"] / r["batch"] for r in res.metrics[1:]]
        ax.plot(xs, ys, ":", color=color, lw=1, label=f"{name}: GP guess on the next batch")
    demo = metrics["baselines"].get("demos_only")
    if demo is not None:
        ax.axhline(demo["test"]["success_rate"], color="0.4", ls="--", label="demonstrations only")
    ax.set_xlabel("environments tried (loop iterations x B)")
    ax.set_ylabel("success rate of the map's mean")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7)
    ax.set_title("self-improvement: success rate vs loop iteration", fontsize=10)
    save_figure(fig, Path(out_dir) / "success_vs_iteration.png")

    # a grid of test environments, failures first: sampled and mean trajectories of the trained map
    with torch.no_grad():
        all_ok = task.success(
            model.mean_trajectory(test_envs), test_envs
        )  # (M,), as in the test metrics
    order = torch.cat([torch.nonzero(~all_ok).flatten(), torch.nonzero(all_ok).flatten()])
    n = min(12, test_envs.shape[0])
    pick = order[:n]
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 3.1 * rows), squeeze=False)
    gen = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        mu, var = model(test_envs[pick])  # (n, N), (n, N)
        w = mu[:, None] + var.sqrt()[:, None] * torch.randn(
            n, 10, mu.shape[-1], generator=gen, dtype=mu.dtype
        )
        samples, means = (
            model.promp.trajectory(w),
            model.promp.trajectory(mu),
        )  # (n, 10, T, 2), (n, T, 2)
        ok = task.success(means, test_envs[pick])
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.axis("off")
            continue
        plot_point_particle(ax, task, test_envs[pick[i]])
        plot_trajectories(
            ax,
            samples[i],
            color="tab:blue",
            lw=0.6,
            alpha=0.35,
            label="samples of the map's distribution",
        )
        plot_trajectories(ax, means[i], color="k", lw=1.8, label="mean")
        ax.set_title(
            f"test env {int(pick[i])}: {'success' if ok[i] else 'FAILURE'}",
            fontsize=8,
            color="k" if ok[i] else "tab:red",
        )
    failures = int((~all_ok).sum())
    fig.suptitle(
        f"held-out environments, failures first ({failures} of {all_ok.numel()} fail): 10 samples "
        "(blue) "
        f"and the mean (black); test success {metrics['test']['success_rate']:.3f}",
        fontsize=10,
    )
    fig.tight_layout()
    legend_below(fig, axes)  # every marker: wall, hole centre, start, goal, samples, mean
    save_figure(fig, Path(out_dir) / "test_grid.png")

    # one moving episode (Fig. 6): frames and a GIF (protorch.figures.online)
    if episode is not None:
        ep = episode.episode(0)
        kw = {k: ep[k] for k in ("positions", "envs", "means", "markers")}
        title = "moving hole and goal, PD tracking the GP's mean"
        plot_episode_frames(
            Path(out_dir) / "online_frames.png",
            **kw,
            dt=ep["dt"],
            success=ep["success"],
            title=title,
        )
        write_episode_gif(
            Path(out_dir) / "online_episode.gif",
            **kw,
            dt=ep["dt"],
            success=ep["success"],
            title=title,
        )
