"""Self-improvement on any task: ``python -m protorch experiment=self_improve task._target_=my_module.MyTask``.

The whole pipeline on a class that follows :class:`~protorch.tasks.SelfImprovementTask`
(``name``, ``num_dof``, ``env_dim``, ``sample_envs``, ``costs``, ``success``,
``demonstrations``), which may live outside protorch:

1. demonstrations (``task.demonstrations(demo_envs, demos_per_env, generator)``, or a folder of
   ``trajK.out`` / ``envK.out`` files with ``task.demos=FOLDER``) -> one ProMP weight Gaussian per
   environment -> the initial data set and GP map;
2. the self-improvement loop (:func:`protorch.loop.self_improve`) with the ``optimizer`` group,
   checkpointed in ``<out_dir>/checkpoint`` (``protorch.load(out_dir)``), resumable;
3. success of the map's mean trajectories on held-out environments, against the
   demonstrations-only map (``demos_only``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

import torch

from ..checks import check_int, check_keys
from ..data.checkpoint import checkpoint_path, load
from ..data.demos import load_human_demos
from ..gp import make_env_map
from ..gp.model import EnvToProMP
from ..loop import LoopResult, demonstration_dataset, self_improve
from ..primitives.promp import ProMP
from ..tasks import check_task_protocol, make_task
from ..viz.paper import save_figure
from .common import evaluation_settings, gp_settings, loop_settings, optimizer_spec

__all__ = ["run", "build_task", "TEST_SEED", "DEMO_SEED_OFFSET"]

TEST_SEED = 2_000_003  # the held-out environments: fixed, never a training seed
DEMO_SEED_OFFSET = 10_007  # generated demonstrations: seed + offset (the loop's pool uses seed)
_BASELINES = ("demos_only",)
_PIPELINE_KEYS = ("demos", "demo_envs", "demos_per_env")


def build_task(task: dict) -> tuple[object, dict]:
    """``(the task object, the pipeline's own task settings)`` from the ``task`` group: ``_target_``
    (a registered name or ``module.Class``), ``demos``, ``demo_envs``, ``demos_per_env``; every
    other key is a constructor keyword argument."""
    cfg = dict(task)
    target = cfg.pop("_target_", None)
    if target is None:
        raise ValueError("task._target_ must name the task class, e.g. task._target_=my_module.MyTask")
    own = {k: cfg.pop(k) for k in _PIPELINE_KEYS if k in cfg}
    try:
        obj = make_task(target, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items()})
    except TypeError as exc:
        raise ValueError(f"task._target_={target!r}: {exc}") from None
    source = str(own.get("demos", "generate"))
    check_task_protocol(obj, demonstrations=source == "generate")
    return obj, {"demos": source, "demo_envs": check_int(own.get("demo_envs", 30), "task.demo_envs", 1),
                 "demos_per_env": check_int(own.get("demos_per_env", 3), "task.demos_per_env", 2)}


def _demonstrations(task, own: dict, seed: int):
    if own["demos"] == "generate":
        gen = torch.Generator().manual_seed(int(seed) + DEMO_SEED_OFFSET)
        demos, envs = task.demonstrations(own["demo_envs"], own["demos_per_env"], gen)
    else:
        folder = Path(own["demos"]).expanduser()
        if not folder.is_dir():
            raise FileNotFoundError(f"task.demos={own['demos']!r}: no such folder; give 'generate' or a folder of "
                                    "trajK.out / envK.out files")
        demos, envs = load_human_demos(folder)
    envs = torch.as_tensor(envs, dtype=torch.float64)
    if envs.ndim != 2 or envs.shape != (len(demos), task.env_dim):
        raise ValueError(f"the demonstrations' environments must be ({len(demos)}, {task.env_dim}) "
                         f"(task.env_dim), got {tuple(envs.shape)}")
    bad = [i for i, d in enumerate(demos) if d.ndim != 2 or d.shape[1] != task.num_dof]
    if bad:
        raise ValueError(f"demonstration {bad[0]} has shape {tuple(demos[bad[0]].shape)}; expected (T, {task.num_dof})")
    return demos, envs


def _test(task, model, envs: torch.Tensor) -> dict:
    with torch.no_grad():
        traj = model.mean_trajectory(envs)  # (Q, T, D)
        ok = task.success(traj, envs)  # (Q,)
        c = task.costs(traj, envs)  # (Q, O)
    return {"success_rate": float(ok.double().mean()), "num_envs": int(envs.shape[0]),
            "cost_median": float(c.sum(-1).median())}


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
    baselines: Sequence[str] = _BASELINES,
    resume: bool = False,
    progress: bool = False,
) -> dict:
    """Run the pipeline (module docstring) into ``out_dir``; return the metrics.

    ``optimizer``: an optimizer group (``{"name": "pro", "beta": ..., ...}``). ``task``: the task
    group (:func:`build_task`). ``gp``: ``backend``, ``alpha``, ``var_floor``, ``nearest_k``.
    ``promp``: ``num_basis``, ``num_steps``. ``loop``: :func:`~protorch.loop.self_improve`'s
    ``num_envs``, ``batch_size``, ``add_only``, ``choice``, ``checkpoint_every``, ``eval_dtype``,
    ``min_var``. ``test``: ``num_envs``, ``seed``. ``baselines``: ``[]`` or ``["demos_only"]``.
    Every setting is checked and the task built before any work.
    """
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    loop_cfg, test_cfg, gp_cfg = dict(loop or {}), dict(test or {}), dict(gp or {})
    check_keys(test_cfg, {"num_envs", "seed"}, "test")
    bad = sorted(set(baselines or []) - set(_BASELINES))
    if bad:
        raise ValueError(f"unknown baseline(s) {bad}; choose from {list(_BASELINES)}")
    obj, own = build_task(task or {})
    cls, opt_kwargs = optimizer_spec(optimizer)
    backend, alpha, var_floor, map_options = gp_settings(gp_cfg, alpha=1.0, var_floor=1e-4, nearest_k=None)
    lk = loop_settings(loop_cfg, num_envs=100)
    test_n, test_seed, _ = evaluation_settings(test_cfg, {}, seed=seed, demo_seed=int(seed) + DEMO_SEED_OFFSET,
                                               test_seed=TEST_SEED, dynamic_seed=TEST_SEED + 1)
    make_env_map(backend, alpha, **map_options)  # refuses a bad backend or option now
    if not resume and checkpoint_path(out_dir).is_file():
        raise FileExistsError(f"{checkpoint_path(out_dir)} already exists: add resume=true to continue that run, "
                              "or choose another hydra.run.dir")
    demos, demo_envs = _demonstrations(obj, own, seed)
    model0 = ProMP(obj.num_dof, **{"num_basis": 10, "num_steps": 100, **dict(promp or {})}, dtype=dtype, device=device)

    def env_map():
        return make_env_map(backend, alpha, dtype=dtype, device=device, **map_options)

    def initial_data():
        return demonstration_dataset(model0, demos, demo_envs, task_name=obj.name, var_floor=var_floor, dtype=dtype)

    test_envs = obj.sample_envs(test_n, torch.Generator().manual_seed(test_seed), dtype=dtype).to(device)
    data0 = initial_data()
    metrics: dict = {"task": f"{type(obj).__module__}.{type(obj).__qualname__}",
                     "demos": {"source": own["demos"], "count": len(demos), "envs": len(data0)},
                     "settings": {"optimizer": optimizer.get("name", cls.__name__.lower()), **lk,
                                  "eval_dtype": str(lk["eval_dtype"]).replace("torch.", ""), "alpha": alpha,
                                  "var_floor": var_floor, "backend": backend}}
    if "demos_only" in (baselines or []):
        gp0 = env_map().fit(data0.env, data0.mean, data0.var, data0.label)
        metrics["demos_only"] = {"test": _test(obj, EnvToProMP(model0, gp0, obj.name), test_envs)}
    res = self_improve(obj, model0, data0, optimizer=cls, optimizer_kwargs=opt_kwargs, env_map=env_map,
                       seed=int(seed), var_floor=var_floor, eval_envs=test_envs, run_dir=out_dir, resume=resume,
                       progress=progress, desc=f"{cls.__name__} loop", **lk)
    model = load(out_dir, device=device, dtype=dtype)  # the checkpoint is what gets evaluated
    metrics["test"] = {**_test(obj, model, test_envs), "seed": test_seed}
    metrics["loop"] = _loop_metrics(res)
    if plot:
        _figure(out_dir, res, metrics)
    metrics["seconds"] = round(time.perf_counter() - t0, 3)
    return metrics


def _loop_metrics(res: LoopResult) -> dict:
    last = res.metrics[-1]
    return {"seconds": round(res.seconds, 3), "envs_tried": len(res.tried),
            "added": sum(int(r.get("added") or 0) for r in res.metrics), "dataset_size": len(res.dataset),
            "success_rate": res.success_rate, "final_eval_success": last.get("eval_success"),
            "steps": int(last["step"]), "resumed_from": res.resumed_from}


def _figure(out_dir: Path, res: LoopResult, metrics: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    x = [r["envs_done"] for r in res.metrics]
    ax.plot(x, [r["eval_success"] for r in res.metrics], "-o", ms=3, label="self-improvement loop: held-out test")
    if "demos_only" in metrics:
        ax.axhline(metrics["demos_only"]["test"]["success_rate"], color="0.4", ls="--", label="demonstrations only")
    ax.set_xlabel("environments tried")
    ax.set_ylabel("success rate of the map's mean")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{metrics['task']}: success vs environments tried", fontsize=9)
    save_figure(fig, out_dir / "success_vs_iteration.png")
