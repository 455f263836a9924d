"""Self-improvement on any task: ``python -m protorch experiment=self_improve
task._target_=my_module.MyTask``.

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

from pathlib import Path

import torch

from ..checks import check_int
from ..data.demos import load_human_demos
from ..figures.paper import save_figure
from ..loop import LoopResult
from ..loop.settings import LOOP_GROUP
from ..tasks import check_task_protocol, make_task
from .loop_run import (
    DEMO_SEED_OFFSET,
    TEST_SEED,
    Outcome,
    SelfImprovementExperiment,
    experiment_functions,
)
from .settings import SettingsError

__all__ = ["run", "build_task", "GenericExperiment", "TEST_SEED", "DEMO_SEED_OFFSET"]

_BASELINES = ("demos_only",)
_PIPELINE_KEYS = ("demos", "demo_envs", "demos_per_env")


def build_task(task: dict) -> tuple[object, dict]:
    """``(the task object, the pipeline's own task settings)`` from the ``task`` group: ``_target_``
    (a registered name or ``module.Class``), ``demos``, ``demo_envs``, ``demos_per_env``; every
    other key is a constructor keyword argument."""
    cfg = dict(task)
    target = cfg.pop("_target_", None)
    if target is None:
        raise SettingsError(
            "task._target_ must name the task class, e.g. task._target_=my_module.MyTask"
        )
    own = {k: cfg.pop(k) for k in _PIPELINE_KEYS if k in cfg}
    try:
        obj = make_task(
            target, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items()}
        )
    except (
        TypeError,
        ValueError,
    ) as exc:  # not importable, not a class, or a constructor argument it lacks
        text = str(exc) if str(exc).startswith("task") else f"task._target_={target!r}: {exc}"
        raise SettingsError(text) from None
    source = str(own.get("demos", "generate"))
    check_task_protocol(obj, demonstrations=source == "generate")
    return obj, {
        "demos": source,
        "demo_envs": check_int(own.get("demo_envs", 30), "task.demo_envs", 1),
        "demos_per_env": check_int(own.get("demos_per_env", 3), "task.demos_per_env", 2),
    }


class GenericExperiment(SelfImprovementExperiment):
    """The skeleton (:class:`SelfImprovementExperiment`) on any task class: its demonstrations
    (generated or from a folder), the held-out test, the demonstrations-only baseline, one
    figure."""

    gp_defaults = {"alpha": 1.0, "var_floor": 1e-4, "nearest_k": None}
    num_envs = 100
    dynamic_seed_default = TEST_SEED + 1
    baseline_names = _BASELINES
    pre_loop_baselines = frozenset({"demos_only"})
    baseline_section = None  # metrics["demos_only"]

    def configure(self, task_cfg: dict, loop_cfg: dict) -> None:
        self.task, self.own = build_task(task_cfg)
        source = self.own["demos"]
        if source != "generate" and not Path(source).expanduser().is_dir():
            raise FileNotFoundError(
                f"task.demos={source!r}: no such folder; give 'generate' or a folder of "
                "trajK.out / envK.out files"
            )

    def make_demonstrations(self) -> None:
        task, own = self.task, self.own
        if own["demos"] == "generate":
            demos, envs = task.demonstrations(
                own["demo_envs"], own["demos_per_env"], self.demo_generator()
            )
        else:
            demos, envs = load_human_demos(Path(own["demos"]).expanduser())
        envs = torch.as_tensor(envs, dtype=torch.float64)
        if envs.ndim != 2 or envs.shape != (len(demos), task.env_dim):
            raise ValueError(
                f"the demonstrations' environments must be ({len(demos)}, {task.env_dim}) "
                f"(task.env_dim), got {tuple(envs.shape)}"
            )
        bad = [i for i, d in enumerate(demos) if d.ndim != 2 or d.shape[1] != task.num_dof]
        if bad:
            raise ValueError(
                f"demonstration {bad[0]} has shape {tuple(demos[bad[0]].shape)}; "
                f"expected (T, {task.num_dof})"
            )
        self.demos, self.demo_envs = demos, envs

    def describe(self) -> dict:
        lk, cls = {k: getattr(self.loop, k) for k in LOOP_GROUP}, self.optimizer[0]
        return {
            "task": f"{type(self.task).__module__}.{type(self.task).__qualname__}",
            "demos": {
                "source": self.own["demos"],
                "count": len(self.demos),
                "envs": len(self.initial_data()),
            },
            "settings": {
                "optimizer": self.optimizer_cfg.get("name", cls.__name__.lower()),
                **lk,
                "alpha": self.alpha,
                "var_floor": self.var_floor,
                "backend": self.backend,
            },
        }

    def test_metrics(self, model) -> dict:
        """Success and median summed cost of the map's mean trajectories on the held-out
        environments."""
        envs = self.test_envs
        with torch.no_grad():
            traj = model.mean_trajectory(envs)  # (Q, T, D)
            ok = self.task.success(traj, envs)  # (Q,)
            c = self.task.costs(traj, envs)  # (Q, O)
        return {
            "success_rate": float(ok.double().mean()),
            "num_envs": int(envs.shape[0]),
            "cost_median": float(c.sum(-1).median()),
        }

    def record(self, metrics: dict, test_m: dict, dyn_m: dict | None, res: LoopResult) -> None:
        metrics["test"] = {**test_m, "seed": self.test_seed}
        metrics["loop"] = self.loop_metrics(res)

    def figures(self, out_dir: Path, outcome: Outcome, metrics: dict) -> None:
        _figure(out_dir, outcome.result, metrics)


_RUN_DOC = """Run the pipeline (module docstring) into ``out_dir``; return the metrics.

    ``optimizer``: an optimizer group (``{"name": "pro", "beta": ..., ...}``). ``task``: the task
    group (:func:`build_task`). ``gp``: ``backend``, ``alpha``, ``var_floor``, ``nearest_k``.
    ``promp``: ``num_basis``, ``num_steps``. ``loop``: :func:`~protorch.loop.self_improve`'s
    ``num_envs``, ``batch_size``, ``add_only``, ``choice``, ``checkpoint_every``, ``eval_dtype``,
    ``min_var``. ``test``: ``num_envs``, ``seed``. ``baselines``: ``[]`` or ``["demos_only"]``.
    Every setting is checked and the task built before any work.
    """
prepare, run = experiment_functions(
    GenericExperiment, baselines=_BASELINES, progress=False, run_doc=_RUN_DOC
)


def _figure(out_dir: Path, res: LoopResult, metrics: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    x = [r["envs_done"] for r in res.metrics]
    ax.plot(
        x,
        [r["eval_success"] for r in res.metrics],
        "-o",
        ms=3,
        label="self-improvement loop: held-out test",
    )
    if "demos_only" in metrics:
        ax.axhline(
            metrics["demos_only"]["test"]["success_rate"],
            color="0.4",
            ls="--",
            label="demonstrations only",
        )
    ax.set_xlabel("environments tried")
    ax.set_ylabel("success rate of the map's mean")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{metrics['task']}: success vs environments tried", fontsize=9)
    save_figure(fig, out_dir / "success_vs_iteration.png")
