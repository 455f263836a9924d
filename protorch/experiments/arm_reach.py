"""Sec. IV-C of the paper: a 7-DoF arm (the Panda shipped with protorch) reaches a target on a
table around a can, and switches between passing it on the left and on the right on the fly.

1. Demonstrations: 20 environments x 3, hand-guided-like end-effector paths passing the can on
   alternating sides, turned into joint trajectories by inverse kinematics; one ProMP weight
   Gaussian per environment and side. Prior knowledge: 2004 environments on a grid with the
   straight end-effector path to the target (by IK) and the average demonstrated variance.
   Every entry carries its homotopy class (:meth:`~protorch.tasks.ArmReachTask.side`) as label.
2. The self-improvement loop (:func:`protorch.loop.self_improve`, PRO) over 2024 random
   environments with the labeller: solutions are stored with their class, the GP map keeps the
   classes apart, a new environment starts from the class whose predicted mean has the lowest
   summed objectives. Checkpointed in ``<out_dir>/checkpoint`` (``protorch.load(out_dir)``),
   resumable.
3. Evaluation with the same label-aware inference on 200 held-out environments, and on 100
   episodes in which the can or the target is moved once or twice while the arm moves
   (:func:`protorch.control.arm.run_arm_episodes`: the map queried every control step, the arm
   switching classes when the objectives of the rest of the motion say so). Baselines in the
   same run: ``labels_off``, the same learned data with the labels dropped (the GP averages
   neighbouring left and right solutions, as the paper's single map would), and
   ``labels_off_loop``, the whole loop run without labels (``<out_dir>/baselines/labels_off_loop``).
4. Figures: top view of both classes' end-effector paths around the can (and the labels-off
   average), a 3-D view of the arm along one trajectory, held-out success vs loop iteration,
   frames and a GIF of a moving episode in which the arm switches sides.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import torch

from ..checks import check_int, check_keys
from ..control.arm import run_arm_episodes
from ..control.switches import geometric_switch_summary
from ..data.checkpoint import checkpoint_path, load
from ..gp import make_env_map
from ..gp.model import label_aware_mean
from ..loop import LoopResult, demonstration_dataset, self_improve
from ..primitives.promp import ProMP, resample
from ..tasks.arm_reach import LEFT, RIGHT, ArmReachTask
from ..viz.arm import experiment_figures
from .common import check_optimizer, evaluation_settings, gp_settings, loop_settings, optimizer_spec

__all__ = ["run", "prepare", "Setup", "TEST_SEED", "DYNAMIC_SEED"]

TEST_SEED = 2_000_003  # the held-out environments: fixed, never a training seed
DYNAMIC_SEED = 3_000_017  # the moving episodes (start environments and moves)
_DEMO_SEED_OFFSET = 10_007  # demonstrations: seed + offset (the loop's pool uses seed)
_BASELINES = ("labels_off", "labels_off_loop")
_TASK_KEYS = {"_target_", "demo_envs", "demos_per_env", "priors", "cost_steps", "margin", "goal_tol", "start_tol",
              "can_radius", "can_height", "clearance", "urdf", "deviation"}
_GP_KEYS = {"backend", "alpha", "var_floor", "nearest_k"}
_LOOP_KEYS = {"num_envs", "batch_size", "add_only", "choice", "checkpoint_every", "eval_dtype", "min_var", "labels",
              "each_label"}
_DYNAMIC_KEYS = {"seed", "episodes", "duration", "hold", "dt", "kp", "moves", "move_window", "place_clearance",
                 "switch_margin"}


@dataclass
class Setup:
    """Everything the experiment builds from its settings (:func:`prepare`); ``benchmarks/arm.py``
    uses it to time the loop."""

    task: ArmReachTask
    promp: ProMP
    demos: list
    demo_envs: torch.Tensor  # (n, 4)
    demo_labels: torch.Tensor  # (n,)
    prior_envs: torch.Tensor  # (P, 4)
    prior_mean: torch.Tensor  # (P, N)
    prior_labels: torch.Tensor  # (P,)
    seed: int
    test_envs: torch.Tensor  # (Q, 4)
    test_seed: int
    dyn_env0: torch.Tensor  # (episodes, 4)
    dyn_cfg: dict
    dyn_seed: int
    optimizer: tuple  # (class, kwargs)
    loop_kwargs: dict  # self_improve keyword arguments (no optimizer, labeler, run_dir, resume, progress)
    env_map: Callable
    var_floor: float
    labels: bool
    each_label: bool
    alpha: float
    nearest_k: int | None
    seconds: dict = field(default_factory=dict)  # demonstrations, priors

    def initial_data(self, labels: bool | None = None):
        """A fresh data set: the demonstrations (one entry per environment and side) and the
        priors (average demonstrated variance); every label 0 with ``labels=False``."""
        labels = self.labels if labels is None else labels
        lab = self.demo_labels if labels else None
        ds = demonstration_dataset(self.promp, self.demos, self.demo_envs, task_name=self.task.name,
                                   var_floor=self.var_floor, dtype=self.promp.basis.dtype, labels=lab)
        if self.prior_envs.shape[0]:
            vbar = ds.var.mean(0).expand_as(self.prior_mean)  # (P, N) the average demonstrated variance
            ds.append(self.prior_envs, self.prior_mean, vbar, label=self.prior_labels if labels else 0,
                      origin="prior", converged=True)
        return ds

    def run_loop(self, labels: bool | None = None, **overrides) -> LoopResult:
        """:func:`~protorch.loop.self_improve` with PRO, with (default) or without labels."""
        labels = self.labels if labels is None else labels
        cls, kwargs = self.optimizer
        kw = {**self.loop_kwargs, **overrides}
        return self_improve(self.task, self.promp, self.initial_data(labels), optimizer=cls, optimizer_kwargs=kwargs,
                            env_map=self.env_map, labeler=self.task.side if labels else None,
                            each_label=labels and self.each_label, **kw)

    def evaluate(self, model) -> tuple[dict, dict, object]:
        """``(test metrics, dynamic metrics, the episodes)`` of a map (an EnvToProMP) with the
        label-aware inference (a map with one label: its plain prediction)."""
        return _test(self.task, model, self.test_envs, self.test_seed), *_dynamic(self.task, model, self.dyn_env0,
                                                                                 self.dyn_cfg, self.dyn_seed)


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
) -> Setup:
    """Validate every setting (clear errors, before any work), make the demonstrations and the
    priors and draw the test environments; see :func:`run` for the settings."""
    task_cfg, gp_cfg = dict(task or {}), dict(gp or {})
    loop_cfg, test_cfg, dyn_cfg = dict(loop or {}), dict(test or {}), dict(dynamic or {})
    for cfg, keys, where in ((task_cfg, _TASK_KEYS, "task"), (gp_cfg, _GP_KEYS, "gp"), (loop_cfg, _LOOP_KEYS, "loop"),
                             (test_cfg, {"num_envs", "seed"}, "test"), (dyn_cfg, _DYNAMIC_KEYS, "dynamic")):
        check_keys(cfg, keys, where)
    check_optimizer(optimizer)
    backend, alpha, var_floor, map_options = gp_settings(gp_cfg, alpha=30.0, var_floor=1e-3, nearest_k=30)
    loop_kwargs = loop_settings(loop_cfg, num_envs=2024)
    labels, each_label = loop_cfg.get("labels", True), loop_cfg.get("each_label", True)
    for name, v in (("labels", labels), ("each_label", each_label)):
        if not isinstance(v, bool):
            raise ValueError(f"loop.{name} must be true or false, got {v!r}")
    test_n, test_seed, dyn_seed = evaluation_settings(
        test_cfg, dyn_cfg, seed=seed, demo_seed=int(seed) + _DEMO_SEED_OFFSET, test_seed=TEST_SEED,
        dynamic_seed=DYNAMIC_SEED)
    episodes = check_int(dyn_cfg.pop("episodes", 100), "dynamic.episodes", 0)
    demo_envs_n = check_int(task_cfg.pop("demo_envs", 20), "task.demo_envs", 1)
    per_env = check_int(task_cfg.pop("demos_per_env", 3), "task.demos_per_env", 2)
    n_priors = check_int(task_cfg.pop("priors", 2004), "task.priors", 0)
    make_env_map(backend, alpha, **map_options)  # refuses a bad backend or option now
    task_cfg.pop("_target_", None)
    arm = ArmReachTask(**task_cfg).to(device)
    model0 = ProMP(arm.num_dof, **{"num_basis": 10, "num_steps": 100, **dict(promp or {})}, dtype=dtype, device=device)
    seconds = {}

    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(int(seed) + _DEMO_SEED_OFFSET)
    demos, demo_envs, demo_labels = arm.demonstrations(demo_envs_n, per_env, gen)
    seconds["demonstrations"] = round(time.perf_counter() - t0, 3)
    t0 = time.perf_counter()
    prior_envs, prior_mean, prior_labels = _priors(arm, model0, n_priors)
    seconds["priors"] = round(time.perf_counter() - t0, 3)

    def env_map():
        return make_env_map(backend, alpha, dtype=dtype, device=device, **map_options)

    loop_kwargs.update(seed=int(seed), var_floor=var_floor, sample_steps=arm.cost_steps)
    test_envs = arm.sample_envs(test_n, torch.Generator().manual_seed(test_seed), dtype=dtype).to(device)
    loop_kwargs["eval_envs"] = test_envs
    return Setup(
        task=arm, promp=model0, demos=demos, demo_envs=demo_envs, demo_labels=demo_labels, prior_envs=prior_envs,
        prior_mean=prior_mean, prior_labels=prior_labels, seed=int(seed), test_envs=test_envs, test_seed=test_seed,
        dyn_env0=arm.sample_envs(episodes, torch.Generator().manual_seed(dyn_seed), dtype=dtype).to(device),
        dyn_seed=dyn_seed,
        dyn_cfg=dyn_cfg, optimizer=optimizer_spec(optimizer),
        loop_kwargs=loop_kwargs, env_map=env_map, var_floor=var_floor, labels=labels, each_label=each_label,
        alpha=alpha, nearest_k=map_options.get("nearest_k"), seconds=seconds,
    )


def _priors(task: ArmReachTask, promp: ProMP, n: int):
    """``n`` grid environments with the straight end-effector path to their target (by IK, one
    per distinct target): ``(envs (n, 4), weight means (n, N), labels (n,))``."""
    if n == 0:
        return torch.zeros(0, 4, dtype=torch.float64), torch.zeros(0, promp.num_weights, dtype=torch.float64), \
            torch.zeros(0, dtype=torch.long)
    grid = task.prior_grid(n)  # (n, 4)
    goals, inverse = torch.unique(grid[:, 2:], dim=0, return_inverse=True)  # (G, 2), (n,)
    any_can = grid[:1, :2].expand(goals.shape[0], 2)  # the straight path does not depend on the can
    q, _ = task.ik_path(task.straight_paths(torch.cat([any_can, goals], 1), promp.num_steps))  # (G, T, 7)
    q = q.to(promp.basis)
    w = promp.weights(q).cpu().to(torch.float64)  # (G, N)
    labels = task.side(q[inverse.to(q.device)], grid.to(q)).cpu()  # (n,) which side the straight path passes
    return grid, w[inverse], labels


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
    baselines: Sequence[str] = _BASELINES,
    resume: bool = False,
    progress: bool = True,
    threads: int | None = 1,
) -> dict:
    """Run the experiment into ``out_dir``; return the metrics (module docstring).

    ``task``: ``demo_envs``, ``demos_per_env``, ``priors`` (number of grid priors) and the
    :class:`~protorch.tasks.ArmReachTask` options (``cost_steps``, ``margin``, ``goal_tol``, ...).
    ``gp``: ``backend``, ``alpha``, ``var_floor``, ``nearest_k``. ``loop``: ``num_envs``,
    ``batch_size``, ``add_only``, ``choice``, ``checkpoint_every``, ``eval_dtype``, ``min_var``,
    ``labels`` (the label-aware map; false runs the paper's single map). ``test``: ``num_envs``,
    ``seed``. ``dynamic``: ``episodes`` plus :func:`~protorch.control.arm.run_arm_episodes`
    options. ``baselines``: any of ``labels_off``, ``labels_off_loop``. ``resume``: continue the
    loops from the checkpoints in ``out_dir``. ``threads``: torch's intra-op threads for the run
    (restored afterwards; ``None`` keeps torch's setting). One is the default: the work is many
    medium-sized tensor operations, and on a shared 2-core machine two threads that wait for each
    other made a loop step 4.5 times slower (README). Every setting is validated before any work starts.
    """
    if threads is not None and (isinstance(threads, bool) or int(threads) != threads or int(threads) < 1):
        raise ValueError(f"threads must be None or an int >= 1, got {threads!r}")
    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(int(threads))
    try:
        return _run(out_dir, seed=seed, device=device, dtype=dtype, optimizer=optimizer, plot=plot, task=task, gp=gp,
                    promp=promp, loop=loop, test=test, dynamic=dynamic, baselines=baselines, resume=resume,
                    progress=progress)
    finally:
        torch.set_num_threads(before)


def _run(out_dir, *, seed, device, dtype, optimizer, plot, task, gp, promp, loop, test, dynamic, baselines, resume,
         progress) -> dict:
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    baselines = list(baselines or [])
    bad = sorted(set(baselines) - set(_BASELINES))
    if bad:
        raise ValueError(f"unknown baseline(s) {bad}; choose from {list(_BASELINES)}")
    base_dir = out_dir / "baselines" / "labels_off_loop"
    if not resume:
        for d in [out_dir] + ([base_dir] if "labels_off_loop" in baselines else []):
            if checkpoint_path(d).is_file():
                raise FileExistsError(
                    f"{checkpoint_path(d)} already exists: add resume=true to continue that run, or choose "
                    "another hydra.run.dir"
                )
    setup = prepare(seed=seed, device=device, dtype=dtype, optimizer=optimizer, task=task, gp=gp, promp=promp,
                    loop=loop, test=test, dynamic=dynamic)
    arm, lk = setup.task, setup.loop_kwargs
    seconds = dict(setup.seconds)
    data0 = setup.initial_data()
    metrics: dict = {
        "demos": {"count": len(setup.demos), "envs": int(setup.demo_envs.unique(dim=0).shape[0]),
                  "entries": int((data0.origin == 0).sum()),
                  "left": int((setup.demo_labels == LEFT).sum()), "right": int((setup.demo_labels == RIGHT).sum()),
                  "success_rate": _demo_success(setup)},
        "priors": {"count": int(setup.prior_envs.shape[0]),
                   "left": int((setup.prior_labels == LEFT).sum()), "right": int((setup.prior_labels == RIGHT).sum())},
        "settings": {"num_envs": lk["num_envs"], "batch_size": lk["batch_size"], "add_only": lk["add_only"],
                     "choice": lk["choice"], "alpha": setup.alpha, "nearest_k": setup.nearest_k, "beta": None if optimizer.get("beta") is None else float(optimizer["beta"]),
                     "var_floor": setup.var_floor, "labels": setup.labels, "each_label": setup.each_label, "max_iter": optimizer.get("max_iter"),
                     "num_samples": optimizer.get("num_samples"), "threads": torch.get_num_threads()},
        "baselines": {},
    }
    # ------------------------------------------------------------------ the loop (label-aware)
    res = setup.run_loop(run_dir=out_dir, resume=resume, progress=progress, desc="PRO loop")
    seconds["loop"] = round(res.seconds, 3)
    model = load(out_dir, device=device, dtype=dtype)  # the checkpoint is what gets evaluated
    t1 = time.perf_counter()
    test_m, dyn_m, episodes = setup.evaluate(model)
    seconds["evaluation"] = round(time.perf_counter() - t1, 3)
    metrics.update(test=test_m, dynamic=dyn_m, loop=_loop_metrics(res, setup.task))
    # ------------------------------------------------------------------ baselines
    off_model = None
    if "labels_off" in baselines:
        t1 = time.perf_counter()
        off_model = load(out_dir, device=device, dtype=dtype)
        em = off_model.env_map
        em.fit(em.E, em.MU, em.VAR)  # the same data, every label 0: left and right averaged
        test_o, dyn_o, _ = setup.evaluate(off_model)
        metrics["baselines"]["labels_off"] = {"test": test_o, "dynamic": dyn_o}
        seconds["labels_off"] = round(time.perf_counter() - t1, 3)
    off_loop = None
    if "labels_off_loop" in baselines:
        t1 = time.perf_counter()
        off_loop = setup.run_loop(labels=False, run_dir=base_dir, resume=resume, progress=progress,
                                  desc="loop, labels off")
        test_l, dyn_l, _ = setup.evaluate(load(base_dir, device=device, dtype=dtype))
        metrics["baselines"]["labels_off_loop"] = {"test": test_l, "dynamic": dyn_l,
                                                   "loop": _loop_metrics(off_loop, setup.task)}
        seconds["labels_off_loop"] = round(time.perf_counter() - t1, 3)
    # ------------------------------------------------------------------ figures
    if plot:
        t1 = time.perf_counter()

        experiment_figures(out_dir, arm, model, off_model, setup.test_envs, res, off_loop, episodes, metrics)
        seconds["figures"] = round(time.perf_counter() - t1, 3)
    seconds["total"] = round(time.perf_counter() - t0, 3)
    metrics["seconds"] = seconds
    return metrics


# ----------------------------------------------------------------------------- evaluation
def _demo_success(setup: Setup) -> float:

    traj = torch.stack([resample(d, setup.promp.num_steps) for d in setup.demos]).to(setup.promp.basis)
    return float(setup.task.success(traj, setup.demo_envs.to(traj)).double().mean())


def _test(task: ArmReachTask, model, envs: torch.Tensor, seed: int) -> dict:
    """Success of the label-aware mean trajectories on the held-out environments."""
    with torch.no_grad():
        best = label_aware_mean(model.env_map, model.promp, task, envs, dtype=model.promp.basis.dtype)
        traj = model.promp.trajectory(best.mean)  # (Q, T, 7)
        ok = task.success(traj, envs)  # (Q,)
        c = task.costs(traj, envs)  # (Q, 3)
        clear = task.can_distance(traj, envs) > task.can_radius + task.margin
        ee = task.ee_path(traj[:, -1])
        goal_err = (ee - task.goal_point(envs)).norm(dim=-1)
        side = task.side(traj, envs)  # (Q,) the side the chosen mean actually passes on
    return {"success_rate": float(ok.double().mean()), "num_envs": int(envs.shape[0]), "seed": int(seed),
            "collision_rate": float((~clear).double().mean()),
            "limit_violation_rate": float((~task.kinematics.within_limits(traj).all(-1)).double().mean()),
            "goal_error_median": float(goal_err.median()), "goal_reached_rate": float((goal_err <= task.goal_tol)
                                                                                     .double().mean()),
            "left": int((side == LEFT).sum()), "right": int((side == RIGHT).sum()),
            "cost_median": float(c.sum(-1).median())}


def _dynamic(task: ArmReachTask, model, env0: torch.Tensor, cfg: dict, seed: int) -> tuple[dict, object]:
    if env0.shape[0] == 0:
        return {"success_rate": float("nan"), "episodes": 0, "switches": 0}, None

    res = run_arm_episodes(model, task, env0, generator=torch.Generator().manual_seed(seed), **cfg)
    geometric = geometric_switch_summary(res, task) if res.weights is not None else {}
    return {**res.summary(), **geometric, "seed": int(seed)}, res


def _loop_metrics(res: LoopResult, task: ArmReachTask) -> dict:
    last = res.metrics[-1]
    learned = res.dataset.origin == 2
    lab = res.dataset.label[learned]
    return {"seconds": round(res.seconds, 3), "envs_tried": len(res.tried),
            "added": int(learned.sum()), "added_left": int((lab == LEFT).sum()), "added_right": int((lab == RIGHT).sum()),
            "dataset_size": len(res.dataset), "success_rate": res.success_rate,
            "final_eval_success": last.get("eval_success"), "steps": int(last["step"]),
            "resumed_from": res.resumed_from}
