"""Sec. IV-B of the paper: a point particle passes the hole of a thick wall (the README's main job).

1. Demonstrations: 30 environments x 3 (synthetic, or the authors' human demonstrations from a
   folder), one ProMP weight Gaussian per environment.
2. The self-improvement loop (:func:`protorch.loop.self_improve`) with PRO over 1000 random
   environments, ``B`` at a time; the data set is checkpointed in ``<out_dir>/checkpoint``
   (``protorch.load(out_dir)`` gives the trained map) and can be resumed.
3. Evaluation of the map's mean trajectories on 200 held-out random environments (a fixed seed
   of their own) and on 100 moving-environment episodes (:func:`protorch.control.particle.run_episodes`,
   the paper's Fig. 6 test), for the trained map and for two baselines in the same run: the GP
   on the demonstrations only, and the same loop with RWR in place of PRO
   (``<out_dir>/baselines/rwr``).
4. Figures: success rate vs loop iteration, a grid of test environments with sampled and mean
   trajectories, Fig. 6-style frames of one moving episode and an animated GIF of it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import torch

from ..checks import check_int, check_keys
from ..control.particle import run_episodes
from ..data.checkpoint import checkpoint_path, load
from ..gp import make_env_map
from ..gp.model import EnvToProMP
from ..loop import LoopResult, demonstration_dataset, self_improve
from ..primitives.promp import ProMP
from ..tasks import PointParticleTask, load_human_demos
from ..viz.online import plot_episode_frames, write_episode_gif
from ..viz.paper import plot_point_particle, plot_trajectories, save_figure
from .common import baseline_spec, check_optimizer, evaluation_settings, gp_settings, loop_settings, optimizer_spec
from .particle_paper import convergence_rule, evaluate_paper, hole_failures, paper_figures, paper_settings

__all__ = ["run", "prepare", "Setup", "TEST_SEED", "DYNAMIC_SEED"]

TEST_SEED = 2_000_003  # the held-out test environments: fixed, never a training seed
DYNAMIC_SEED = 3_000_017  # the moving-environment episodes (start environments and walks)
_DEMO_SEED_OFFSET = 10_007  # synthetic demonstrations: seed + offset (the loop's pool uses seed)
_BASELINES = ("demos_only", "rwr")
_TASK_KEYS = {"_target_", "objectives", "fixed_start", "infinite_wall", "demos", "demo_envs", "demos_per_env"}
_GP_KEYS = {"backend", "alpha", "var_floor", "nearest_k"}
_LOOP_KEYS = {"num_envs", "batch_size", "add_only", "choice", "checkpoint_every", "eval_dtype", "min_var",
              "stop_when_solved"}
_DYNAMIC_KEYS = {"seed", "episodes", "duration", "hold", "dt", "kp", "kd", "step_std", "start", "goal_tol"}


@dataclass
class Setup:
    """Everything the experiment builds from its settings (:func:`prepare`): the task, the ProMP,
    the demonstrations, the held-out and moving-environment test sets and the loop's settings.
    ``benchmarks/loop.py`` uses it to time the loop at other batch sizes."""

    task: PointParticleTask
    promp: ProMP
    demos: list
    demo_envs: torch.Tensor
    source: str
    seed: int
    test_envs: torch.Tensor  # (Q, E)
    test_seed: int
    dyn_env0: torch.Tensor  # (episodes, E)
    dyn_cfg: dict
    dyn_seed: int
    optimizers: dict  # name -> (class, kwargs)
    loop_kwargs: dict  # self_improve keyword arguments (no optimizer, run_dir, resume, progress)
    env_map: Callable
    var_floor: float
    paper_cfg: dict | None = None  # the authors' moving test (protorch.experiments.particle_paper)

    def initial_data(self):
        """A fresh data set of the demonstrations (each loop grows its own)."""
        return demonstration_dataset(self.promp, self.demos, self.demo_envs, task_name=self.task.name,
                                     var_floor=self.var_floor, dtype=self.promp.basis.dtype)

    def run_loop(self, method: str = "pro", **overrides) -> LoopResult:
        """:func:`~protorch.loop.self_improve` with ``method``'s optimiser ("pro" / "rwr");
        ``overrides`` replace loop settings (``batch_size``, ``num_envs``, ``run_dir``, ...)."""
        cls, kwargs = self.optimizers[method]
        kw = {**self.loop_kwargs, **overrides}
        return self_improve(self.task, self.promp, self.initial_data(), optimizer=cls, optimizer_kwargs=kwargs,
                            env_map=self.env_map, **kw)

    def evaluate(self, model) -> tuple[dict, dict, object]:
        """``(test metrics, dynamic metrics, the episodes)`` of a map (an EnvToProMP)."""
        return _test(self.task, model, self.test_envs, self.test_seed), *_dynamic(
            self.task, model, self.dyn_env0, self.dyn_cfg, self.dyn_seed)


def prepare(
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    dtype: torch.dtype = torch.float64,
    optimizer: dict,
    task: dict | None = None,
    gp: dict | None = None,
    promp: dict | None = None,
    loop: dict | None = None,
    test: dict | None = None,
    dynamic: dict | None = None,
    baseline_optimizer: dict | None = None,
    dynamic_paper: dict | None = None,
) -> Setup:
    """Validate every setting (clear errors, before any work), load or synthesise the
    demonstrations and draw the test environments; see :func:`run` for the settings."""
    task_cfg, gp_cfg = dict(task or {}), dict(gp or {})
    loop_cfg, test_cfg, dyn_cfg = dict(loop or {}), dict(test or {}), dict(dynamic or {})
    for cfg, keys, where in ((task_cfg, _TASK_KEYS, "task"), (gp_cfg, _GP_KEYS, "gp"), (loop_cfg, _LOOP_KEYS, "loop"),
                             (test_cfg, {"num_envs", "seed"}, "test"), (dyn_cfg, _DYNAMIC_KEYS, "dynamic")):
        check_keys(cfg, keys, where)
    check_optimizer(optimizer)
    backend, alpha, var_floor, map_options = gp_settings(gp_cfg, alpha=1e-3, var_floor=1e-4, nearest_k=None)
    lk = loop_settings(loop_cfg, num_envs=1000)
    test_n, test_seed, dyn_seed = evaluation_settings(
        test_cfg, dyn_cfg, seed=seed, demo_seed=int(seed) + _DEMO_SEED_OFFSET, test_seed=TEST_SEED,
        dynamic_seed=DYNAMIC_SEED)
    episodes = check_int(dyn_cfg.pop("episodes", 100), "dynamic.episodes", 0)
    paper_cfg = paper_settings(dynamic_paper, training_seeds=(int(seed), int(seed) + _DEMO_SEED_OFFSET))

    make_env_map(backend, alpha, **map_options)  # refuses a bad backend or option now
    point = PointParticleTask(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in task_cfg.items()
                                 if k in ("objectives", "fixed_start", "infinite_wall")})
    source = str(task_cfg.get("demos", "synthetic"))
    demo_envs_n = check_int(task_cfg.get("demo_envs", 30), "task.demo_envs", 1)
    per_env = check_int(task_cfg.get("demos_per_env", 3), "task.demos_per_env", 2)
    if source == "synthetic":
        gen = torch.Generator().manual_seed(int(seed) + _DEMO_SEED_OFFSET)
        demos, demo_envs = point.demonstrations(demo_envs_n, per_env, gen)
    else:
        folder = Path(source).expanduser()
        if not folder.is_dir():
            raise FileNotFoundError(
                f"task.demos={source!r}: no such folder (resolved to {folder.resolve()}); give "
                "'synthetic' or a folder of trajK.out / envK.out files"
            )
        if point.fixed_start is not None:
            raise ValueError("the human demonstrations have 6-D environments: leave task.fixed_start unset")
        demos, demo_envs = load_human_demos(folder)
    model0 = ProMP(2, **{"num_basis": 10, "num_steps": 100, **dict(promp or {})}, dtype=dtype, device=device)

    def env_map():
        return make_env_map(backend, alpha, dtype=dtype, device=device, **map_options)

    def solved(traj, env):  # the authors' acceptance margins, looser on the end points
        return point.success(traj, env, tol=0.05) & (point.clearance(traj, env) >= 0.1)

    loop_kwargs = dict(**lk, solved=solved if loop_cfg.get("stop_when_solved", False) else None, seed=int(seed),
                       var_floor=var_floor)
    test_envs = point.sample_envs(test_n, torch.Generator().manual_seed(test_seed), dtype=dtype).to(device)
    loop_kwargs["eval_envs"] = test_envs
    return Setup(
        task=point, promp=model0, demos=demos, demo_envs=demo_envs, source=source, seed=int(seed),
        test_envs=test_envs, test_seed=test_seed,
        dyn_env0=point.sample_envs(episodes, torch.Generator().manual_seed(dyn_seed), dtype=dtype).to(device),
        dyn_seed=dyn_seed,
        dyn_cfg=dyn_cfg,
        optimizers={m: (cls, convergence_rule(kw, point.objectives))
                    for m, (cls, kw) in (("pro", optimizer_spec(optimizer)),
                                         ("rwr", baseline_spec(optimizer, baseline_optimizer)))},
        loop_kwargs=loop_kwargs, env_map=env_map, var_floor=var_floor, paper_cfg=paper_cfg,
    )


def run(
    out_dir: Path,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    dtype: torch.dtype = torch.float64,
    optimizer: dict,
    plot: bool = True,
    task: dict | None = None,
    gp: dict | None = None,
    promp: dict | None = None,
    loop: dict | None = None,
    test: dict | None = None,
    dynamic: dict | None = None,
    dynamic_paper: dict | None = None,
    baselines: Sequence[str] = _BASELINES,
    resume: bool = False,
    progress: bool = True,
    baseline_optimizer: dict | None = None,
) -> dict:
    """Run the experiment into ``out_dir``; return the metrics (see the module docstring).

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
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    baselines = list(baselines or [])
    bad = sorted(set(baselines) - set(_BASELINES))
    if bad:
        raise ValueError(f"unknown baseline(s) {bad}; choose from {list(_BASELINES)}")
    setup = prepare(seed=seed, device=device, dtype=dtype, optimizer=optimizer, task=task, gp=gp, promp=promp,
                    loop=loop, test=test, dynamic=dynamic, baseline_optimizer=baseline_optimizer,
                    dynamic_paper=dynamic_paper)
    rwr_dir = out_dir / "baselines" / "rwr"
    if not resume:
        for d in [out_dir] + ([rwr_dir] if "rwr" in baselines else []):
            if checkpoint_path(d).is_file():
                raise FileExistsError(
                    f"{checkpoint_path(d)} already exists: add resume=true to continue that run, or choose "
                    "another hydra.run.dir"
                )
    point = setup.task
    lk = setup.loop_kwargs
    metrics: dict = {
        "demos": {"source": setup.source, "count": len(setup.demos), "envs": len(setup.initial_data())},
        "settings": {"num_envs": lk["num_envs"], "batch_size": lk["batch_size"], "add_only": lk["add_only"],
                     "choice": lk["choice"], "alpha": float((gp or {}).get("alpha", 1e-3)),
                     "beta": None if optimizer.get("beta") is None else float(optimizer["beta"]), "var_floor": setup.var_floor,
                     "objectives": point.objectives},
        "baselines": {},
    }
    # ------------------------------------------------------------------ baseline: demonstrations only
    if "demos_only" in baselines:
        data0 = setup.initial_data()
        gp0 = setup.env_map().fit(data0.env, data0.mean, data0.var, data0.label)
        test_m, dyn_m, _ = setup.evaluate(EnvToProMP(setup.promp, gp0, point.name))
        metrics["baselines"]["demos_only"] = {"test": test_m, "dynamic": dyn_m}
    # ------------------------------------------------------------------ PRO loop (the method)
    pro = setup.run_loop("pro", run_dir=out_dir, resume=resume, progress=progress, desc="PRO loop")
    model = load(out_dir, device=device, dtype=dtype)  # the checkpoint is what gets evaluated
    test_m, dyn_m, episode = setup.evaluate(model)
    metrics.update(test=test_m, dynamic=dyn_m, loop=_loop_metrics(pro))
    metrics["dynamic_paper"], paper_ep = evaluate_paper(point, model, setup.paper_cfg, dtype=dtype, device=device)
    if point.objectives == "hole":
        metrics["hole_analysis"] = hole_failures(point, model.mean_trajectory(setup.test_envs), setup.test_envs)
    # ------------------------------------------------------------------ baseline: RWR in the loop
    rwr = None
    if "rwr" in baselines:
        rwr = setup.run_loop("rwr", run_dir=rwr_dir, resume=resume, progress=progress, desc="RWR loop")
        test_r, dyn_r, _ = setup.evaluate(load(rwr_dir, device=device, dtype=dtype))
        metrics["baselines"]["rwr"] = {"test": test_r, "dynamic": dyn_r, "loop": _loop_metrics(rwr)}
    # ------------------------------------------------------------------ figures
    if plot:
        _figures(out_dir, point, model, setup.test_envs, pro, rwr, metrics, episode, seed)
        paper_figures(out_dir, paper_ep)
    metrics["seconds"] = round(time.perf_counter() - t0, 3)
    return metrics


# ----------------------------------------------------------------------------- evaluation
def _test(task, model, envs, seed: int) -> dict:
    """Success of the map's mean trajectories on the held-out environments."""
    with torch.no_grad():
        traj = model.mean_trajectory(envs)  # (Q, T, 2)
        ok = task.success(traj, envs)  # (Q,)
        c = task.costs(traj, envs)  # (Q, 3)
    return {"success_rate": float(ok.double().mean()), "num_envs": int(envs.shape[0]),
            "seed": int(seed), "collision_rate": float(task.collides(traj, envs).double().mean()),
            "start_error_median": float(c[:, 0].median()), "goal_error_median": float(c[:, 2].median())}


def _dynamic(task, model, env0, cfg, seed: int) -> tuple[dict, object]:
    """The moving-environment episodes (:mod:`protorch.control.particle`)."""
    if env0.shape[0] == 0:
        return {"success_rate": float("nan"), "episodes": 0}, None

    res = run_episodes(model, task, env0, generator=torch.Generator().manual_seed(seed), **cfg)
    return {**res.summary(), "seed": int(seed)}, res


def _loop_metrics(res: LoopResult) -> dict:
    last = res.metrics[-1]
    added = sum(int(r.get("added") or 0) for r in res.metrics)
    return {"seconds": round(res.seconds, 3), "envs_tried": len(res.tried), "added": added,
            "dataset_size": len(res.dataset), "success_rate": res.success_rate,
            "final_eval_success": last.get("eval_success"), "steps": int(last["step"]),
            "resumed_from": res.resumed_from}


# ----------------------------------------------------------------------------- figures
def _figures(out_dir, task, model, test_envs, pro, rwr, metrics, episode, seed) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    # success rate vs loop iteration, on the held-out environments
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, res, color in (("PRO loop", pro, "tab:blue"), ("RWR loop", rwr, "tab:red")):
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
        all_ok = task.success(model.mean_trajectory(test_envs), test_envs)  # (M,), as in the test metrics
    order = torch.cat([torch.nonzero(~all_ok).flatten(), torch.nonzero(all_ok).flatten()])
    n = min(12, test_envs.shape[0])
    pick = order[:n]
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 3.1 * rows), squeeze=False)
    gen = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        mu, var = model(test_envs[pick])  # (n, N), (n, N)
        w = mu[:, None] + var.sqrt()[:, None] * torch.randn(n, 10, mu.shape[-1], generator=gen, dtype=mu.dtype)
        samples, means = model.promp.trajectory(w), model.promp.trajectory(mu)  # (n, 10, T, 2), (n, T, 2)
        ok = task.success(means, test_envs[pick])
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.axis("off")
            continue
        plot_point_particle(ax, task, test_envs[pick[i]])
        plot_trajectories(ax, samples[i], color="tab:blue", lw=0.6, alpha=0.35)
        plot_trajectories(ax, means[i], color="k", lw=1.8, label="mean")
        ax.set_title(f"test env {int(pick[i])}: {'success' if ok[i] else 'FAILURE'}", fontsize=8,
                     color="k" if ok[i] else "tab:red")
    failures = int((~all_ok).sum())
    fig.suptitle(f"held-out environments, failures first ({failures} of {all_ok.numel()} fail): 10 samples (blue) "
                 f"and the mean (black); test success {metrics['test']['success_rate']:.3f}", fontsize=10)
    fig.tight_layout()
    save_figure(fig, Path(out_dir) / "test_grid.png")

    # one moving episode (Fig. 6): frames and a GIF (protorch.viz.online)
    if episode is not None:

        ep = episode.episode(0)
        kw = {k: ep[k] for k in ("positions", "envs", "means", "markers")}
        title = "moving hole and goal, PD tracking the GP's mean"
        plot_episode_frames(Path(out_dir) / "online_frames.png", **kw, dt=ep["dt"], success=ep["success"],
                            title=title)
        write_episode_gif(Path(out_dir) / "online_episode.gif", **kw, dt=ep["dt"], success=ep["success"],
                          title=title)
