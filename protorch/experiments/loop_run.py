"""An experiment around the self-improvement loop, written once for every task that runs it.

The loop itself is the library's (:mod:`protorch.loop`: :func:`~protorch.loop.self_improve`,
:class:`~protorch.loop.LoopSettings`); this module is the app's run of it: the settings groups
checked and turned into a ``LoopSettings`` (:func:`~protorch.experiments.common.loop_settings`),
the demonstrations, the tests, the baselines (a loop baseline in a worker process,
:mod:`~protorch.experiments.loop_worker`) and the metrics. :class:`SelfImprovementExperiment` is
the skeleton of ``point_particle``, ``arm_reach`` and ``self_improve`` (the app for a user's
task, :mod:`~protorch.experiments.self_improve`):

1. settings checked (every group, before any work; :meth:`~SelfImprovementExperiment.configure`
   adds the task's own checks and builds the task object);
2. :meth:`~SelfImprovementExperiment.build`: the demonstrations -> the task contract checked on
   them (:meth:`~SelfImprovementExperiment.check_task`) -> the priors -> the held-out and
   moving-test environments -> the loop's options;
3. :meth:`~SelfImprovementExperiment.run`: refuse a finished run (unless ``resume``), the
   baselines that need no loop, the self-improvement loop (:func:`protorch.loop.self_improve`,
   checkpointed in ``<out_dir>/checkpoint``, resumable), the checkpoint loaded and evaluated
   (held-out test, moving test), the other baselines (a loop baseline in
   ``<out_dir>/baselines/<name>``), the figures, the metrics.

A subclass supplies only its task-specific parts, one method each: ``configure`` (the task and
its settings), ``make_demonstrations`` / ``make_priors``, ``initial_data``, ``loop_arguments``
(the optimiser, data set and labeller of the method and of each loop baseline), ``describe``
(the metrics' header), ``test_metrics``, ``moving_test``, ``loop_metrics``, ``baseline`` (a
baseline without a loop of its own), ``record`` and ``figures``.
"""

from __future__ import annotations

import copy
import dataclasses
import inspect
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import torch

from ..checks import check_int, check_keys
from ..data.checkpoint import checkpoint_path, load
from ..gp import make_env_map
from ..gp.model import EnvToProMP
from ..loop import (
    LoopResult,
    LoopSettings,
    OptimizerSpec,
    Run,
    can_refill,
    demonstration_dataset,
    self_improve,
)
from ..loop.settings import LOOP_GROUP
from ..primitives.promp import ProMP, resample
from ..tasks import check_task_outputs
from ..threads import beside_workers, core_budget, torch_threads
from .common import (
    check_optimizer,
    evaluation_settings,
    gp_settings,
    loop_settings,
    optimizer_spec,
    problem_arguments,
)
from .loop_worker import LoopWorker, encode_settings

__all__ = [
    "experiment_functions",
    "SelfImprovementExperiment",
    "Outcome",
    "TEST_SEED",
    "DYNAMIC_SEED",
    "DEMO_SEED_OFFSET",
    "GP_KEYS",
    "LOOP_KEYS",
    "loop_summary",
]

TEST_SEED = 2_000_003  # the held-out test environments: fixed, never a training seed
DYNAMIC_SEED = 3_000_017  # the moving-environment episodes (start environments and moves)
DEMO_SEED_OFFSET = 10_007  # generated demonstrations: seed + offset (the loop's pool uses seed)
GP_KEYS = frozenset({"backend", "alpha", "var_floor", "nearest_k", "neighbours"})
LOOP_KEYS = frozenset(LOOP_GROUP)
# run_loop's overrides that go to the Run (the rest are LoopSettings fields or self_improve's own)
_RUN_KEYS = {"run_dir": "dir", "resume": "resume", "progress": "progress", "on_step": "on_step"}
_SETTINGS_KEYS = frozenset(f.name for f in dataclasses.fields(LoopSettings))


@dataclass
class Outcome:
    """What the figures draw: the trained map, its loop, its moving episodes and each baseline's
    artefact (a :class:`~protorch.loop.LoopResult` for a loop baseline, else what
    :meth:`SelfImprovementExperiment.baseline` returned)."""

    model: object
    result: LoopResult
    episodes: object
    baselines: dict = field(default_factory=dict)


def loop_summary(res: LoopResult) -> dict:
    """The loop's metrics entry: time, environments tried, rollouts (the optimiser's samples
    evaluated), solutions added, success rates."""
    last = res.metrics[-1]
    return {
        "seconds": round(res.seconds, 3),
        "envs_tried": len(res.tried),
        "rollouts": sum(int(r.get("rollouts") or 0) for r in res.metrics),
        "added": sum(int(r.get("added") or 0) for r in res.metrics),
        "dataset_size": len(res.dataset),
        "success_rate": res.success_rate,
        "final_eval_success": last.get("eval_success"),
        "steps": int(last["step"]),
        "resumed_from": res.resumed_from,
    }


class SelfImprovementExperiment:
    """One self-improvement experiment: its settings (checked by the constructor, before any
    work), what it builds (:meth:`build`) and the run (:meth:`run`). See the module docstring."""

    task_keys: frozenset | None = (
        None  # the task.* settings accepted (None: any; configure checks them)
    )
    loop_keys: frozenset = frozenset()  # loop.* settings beyond LOOP_KEYS
    dynamic_keys: frozenset | None = (
        None  # the moving test's dynamic.* settings (None: no moving test)
    )
    gp_defaults: dict = {"alpha": 1.0, "var_floor": 1e-4, "nearest_k": None}
    num_envs = 1000  # the loop's default number of environments
    test_seed_default, dynamic_seed_default = TEST_SEED, DYNAMIC_SEED
    baseline_names: tuple = ()  # in the order they run
    pre_loop_baselines: frozenset = frozenset()  # baselines computed before the loop
    loop_baselines: frozenset = (
        frozenset()
    )  # baselines with a loop of their own (<out_dir>/baselines/<name>)
    baseline_section: str | None = "baselines"  # where their metrics go (None: the top level)
    # the task the loop optimises and accepts with, where it differs from the tests' (None: task)
    loop_task = None

    def __new__(cls, *args, **settings):
        self = super().__new__(cls)
        self.constructed_with = copy.deepcopy(
            settings
        )  # what a worker process rebuilds the experiment from
        return self

    def __init__(
        self,
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
    ):
        task_cfg, gp_cfg, loop_cfg = dict(task or {}), dict(gp or {}), dict(loop or {})
        test_cfg, dyn_cfg = dict(test or {}), dict(dynamic or {})
        for cfg, keys, where in (
            (task_cfg, self.task_keys, "task"),
            (gp_cfg, GP_KEYS, "gp"),
            (loop_cfg, LOOP_KEYS | self.loop_keys, "loop"),
            (test_cfg, {"num_envs", "seed"}, "test"),
            (dyn_cfg, self.dynamic_keys or frozenset(), "dynamic"),
        ):
            if keys is not None:
                check_keys(cfg, keys, where)
        check_optimizer(optimizer)
        self.seed, self.device, self.dtype, self.optimizer_cfg = int(seed), device, dtype, optimizer
        self.backend, self.alpha, self.var_floor, self.map_options = gp_settings(
            gp_cfg, **self.gp_defaults
        )
        # the loop group's values, as checked (build adds the seed and the map's var_floor)
        self.loop = loop_settings(loop_cfg, num_envs=self.num_envs)
        self.test_n, self.test_seed, self.dyn_seed = evaluation_settings(
            test_cfg,
            dyn_cfg,
            seed=seed,
            demo_seed=int(seed) + DEMO_SEED_OFFSET,
            test_seed=self.test_seed_default,
            dynamic_seed=self.dynamic_seed_default,
        )
        self.episodes = (
            check_int(dyn_cfg.pop("episodes", 100), "dynamic.episodes", 0)
            if self.dynamic_keys
            else 0
        )
        self.dyn_cfg = dyn_cfg  # the moving test's options
        make_env_map(
            self.backend, self.alpha, **self.map_options
        )  # refuses a bad backend or option now
        self.promp_cfg = {"num_basis": 10, "num_steps": 100, **dict(promp or {})}
        self.optimizer = optimizer_spec(optimizer)  # (class, kwargs)
        if self.loop.refill is True and not can_refill(*self.optimizer):
            raise ValueError(
                f"loop.refill=true needs an optimiser that restarts single problems (pro with "
                "relevance_every=1, rwr, cem), not "
                f"{optimizer.get('name', self.optimizer[0].__name__)}: "
                f"set loop.refill=auto or false"
            )
        self.seconds: dict = {}
        self.refill_used: bool | None = None  # loop.refill as the method's loop ran it (run_loop)
        self.configure(task_cfg, loop_cfg)

    # ------------------------------------------------------------------ task-specific parts
    def configure(self, task_cfg: dict, loop_cfg: dict) -> None:
        """Check the task's own settings and set ``self.task`` (cheap: no demonstrations yet)."""
        raise NotImplementedError

    def make_demonstrations(self) -> None:
        """Set ``self.demos`` (a list of ``(T, D)`` trajectories) and ``self.demo_envs`` ``(n,
        E)``."""
        raise NotImplementedError

    def make_priors(self) -> None:
        """Prior knowledge beyond the demonstrations (none by default)."""

    def demo_generator(self) -> torch.Generator:
        """The generator of generated demonstrations (``seed + DEMO_SEED_OFFSET``)."""
        return torch.Generator().manual_seed(self.seed + DEMO_SEED_OFFSET)

    def loop_options(self) -> dict:
        """The task's own :class:`~protorch.loop.LoopSettings` fields (e.g. ``sample_steps``) and
        :func:`~protorch.loop.self_improve` keyword arguments (e.g. ``solved``); none by
        default."""
        return {}

    def initial_data(self):
        """A fresh data set of the demonstrations (each loop grows its own)."""
        return demonstration_dataset(
            self.promp,
            self.demos,
            self.demo_envs,
            task_name=self.task.name,
            var_floor=self.var_floor,
            dtype=self.promp.basis.dtype,
        )

    def loop_arguments(self, variant: str | None) -> dict:
        """``optimizer``, ``optimizer_kwargs`` and ``dataset`` (plus e.g. ``labeler`` and
        ``each_label``) of the method's loop (``variant=None``) or of the loop baseline
        ``variant``."""
        cls, kwargs = self.optimizer
        return {"optimizer": cls, "optimizer_kwargs": kwargs, "dataset": self.initial_data()}

    def describe(self) -> dict:
        """The metrics' header (demonstrations, settings), written before the loop runs."""
        return {}

    def test_metrics(self, model) -> dict:
        """The map's held-out test on ``self.test_envs``."""
        raise NotImplementedError

    def moving_test(self, model) -> tuple[dict | None, object]:
        """``(metrics, episodes)`` of the moving test on ``self.dyn_env0`` (``(None, None)``:
        none)."""
        return None, None

    def loop_metrics(self, res: LoopResult) -> dict:
        """The loop's metrics entry (:func:`loop_summary`) and whether its slots were refilled
        (``loop.refill=auto`` resolved for the loop's optimiser)."""
        return {**loop_summary(res), "refill": self.refill_used}

    def baseline(self, name: str, out_dir: Path, model) -> tuple[dict, object]:
        """A baseline without a loop of its own: ``(metrics entry, artefact for the figures)``;
        ``model`` is the trained map (``None`` before the loop). ``demos_only``: the GP map of
        the demonstrations only."""
        if name != "demos_only":
            raise NotImplementedError(f"baseline {name!r}")
        data0 = self.initial_data()
        gp0 = self.env_map().fit(data0.env, data0.mean, data0.var, data0.label)
        demo_model = EnvToProMP(self.promp, gp0, self.task.name)
        return self.entry(*self.evaluate(demo_model)[:2]), demo_model

    def record(self, metrics: dict, test_m: dict, dyn_m: dict | None, res: LoopResult) -> None:
        """Put the trained map's results into ``metrics``."""
        metrics.update(self.entry(test_m, dyn_m, loop=self.loop_metrics(res)))

    def extra_tests(self, model) -> dict:
        """Further tests of the trained map, as metrics sections (none by default)."""
        return {}

    def figures(self, out_dir: Path, outcome: Outcome, metrics: dict) -> None:
        """Draw the experiment's figures into ``out_dir`` (none by default)."""

    def seconds_metrics(self) -> float | dict:
        """The metrics' ``seconds`` entry: the run's total by default (``self.seconds`` has the
        phases)."""
        return self.seconds["total"]

    # ------------------------------------------------------------------ the skeleton
    def build(self) -> "SelfImprovementExperiment":
        """Demonstrations, priors, the ProMP, the test environments and the loop's options."""
        self.promp = ProMP(self.num_dof(), **self.promp_cfg, dtype=self.dtype, device=self.device)
        for name, make in (
            ("demonstrations", self.make_demonstrations),
            ("task_check", self.check_task),
            ("priors", self.make_priors),
        ):
            t0 = time.perf_counter()
            make()
            self.seconds[name] = round(time.perf_counter() - t0, 3)
        self.test_envs = self.sample(self.test_n, self.test_seed)  # (Q, E)
        self.dyn_env0 = (
            self.sample(self.episodes, self.dyn_seed) if self.dynamic_keys else None
        )  # (episodes, E)
        self.loop = self.loop.replace(seed=self.seed, var_floor=self.var_floor)
        return self

    def check_task(self) -> None:
        """The task contract, before any work: ``costs`` and ``success`` called once on the
        demonstrations (resampled to the ProMP's ``T`` steps) and once in the loop's batched form
        and evaluation dtype (:func:`~protorch.tasks.check_task_outputs`; a
        :class:`~protorch.tasks.TaskContractError` names the method and both shapes)."""
        traj = torch.stack(
            [resample(torch.as_tensor(d), self.promp.num_steps) for d in self.demos]
        )  # (n, T, D)
        traj = traj.to(self.promp.basis)
        check_task_outputs(
            self.task,
            traj,
            torch.as_tensor(self.demo_envs).to(traj),
            dtype=self.loop.torch_eval_dtype,
        )

    def num_dof(self) -> int:
        return self.task.num_dof

    def sample(self, n: int, seed: int) -> torch.Tensor:
        gen = torch.Generator().manual_seed(seed)
        return self.task.sample_envs(n, gen, dtype=self.dtype).to(self.device)  # (n, E)

    def env_map(self):
        """A fresh (unfitted) GP map with the experiment's settings."""
        return make_env_map(
            self.backend, self.alpha, dtype=self.dtype, device=self.device, **self.map_options
        )

    def run_loop(self, variant: str | None = None, **overrides) -> LoopResult:
        """:func:`~protorch.loop.self_improve` of the method (``variant=None``) or of the loop
        baseline ``variant``; ``overrides`` replace :class:`~protorch.loop.LoopSettings` fields
        (``batch_size``, ``threads``, ...) or set the :class:`~protorch.loop.Run` (``run_dir``,
        ``resume``, ``progress``, ``on_step``)."""
        args = {**self.loop_options(), **self.loop_arguments(variant), **overrides}
        cls, data = args.pop("optimizer"), args.pop("dataset")
        spec = OptimizerSpec(
            cls, problem_arguments(cls, args.pop("optimizer_kwargs"), self.task, self.promp)
        )
        desc = f"{cls.__name__} loop" + ("" if variant is None else f" ({variant})")
        run = Run(desc=desc, **{_RUN_KEYS[k]: args.pop(k) for k in list(args) if k in _RUN_KEYS})
        settings = self.loop.replace(**{k: args.pop(k) for k in list(args) if k in _SETTINGS_KEYS})
        if settings.refill == "auto":  # on where the loop's optimiser can restart single problems
            settings = settings.replace(refill=can_refill(spec))
        if variant is None:
            self.refill_used = bool(settings.refill)  # for the metrics (self.loop keeps "auto")
        task = self.task if self.loop_task is None else self.loop_task
        return self_improve(
            task,
            self.promp,
            data,
            spec,
            self.env_map,
            settings,
            run,
            eval_envs=self.test_envs,
            **args,
        )

    def evaluate(self, model) -> tuple[dict, dict | None, object]:
        """``(test metrics, moving-test metrics, the episodes)`` of a map (an EnvToProMP)."""
        return self.test_metrics(model), *self.moving_test(model)

    @staticmethod
    def entry(test_m: dict, dyn_m: dict | None, **more) -> dict:
        return {"test": test_m, **({} if dyn_m is None else {"dynamic": dyn_m}), **more}

    def check_baselines(self, baselines: Sequence[str] | None) -> list[str]:
        chosen = list(baselines or [])
        bad = sorted(set(chosen) - set(self.baseline_names))
        if bad:
            raise ValueError(f"unknown baseline(s) {bad}; choose from {list(self.baseline_names)}")
        return [b for b in self.baseline_names if b in chosen]

    def refuse_finished(self, out_dir: Path, chosen: list[str]) -> None:
        for d in [out_dir] + [
            out_dir / "baselines" / b for b in chosen if b in self.loop_baselines
        ]:
            if checkpoint_path(d).is_file():
                raise FileExistsError(
                    f"{checkpoint_path(d)} already exists: add resume=true to continue that run, "
                    "or choose another hydra.run.dir"
                )

    def run_baseline(
        self,
        name: str,
        out_dir: Path,
        model,
        resume: bool,
        progress: bool,
        worker: LoopWorker | None = None,
    ) -> tuple[dict, object]:
        """A baseline's metrics entry and artefact; a loop baseline whose ``worker`` ran its loop
        is read back from the worker's finished checkpoint."""
        if name not in self.loop_baselines:
            return self.baseline(name, out_dir, model)
        run_dir = out_dir / "baselines" / name
        if worker is not None:
            report = worker.wait()
            resume, progress = True, False  # the loop is finished: resuming it reads its checkpoint
        res = self.run_loop(name, run_dir=run_dir, resume=resume, progress=progress)
        if worker is not None:
            res.resumed_from = report["resumed_from"]  # the worker's loop's, not this read-back's
        test_m, dyn_m, _ = self.evaluate(load(run_dir, device=self.device, dtype=self.dtype))
        return self.entry(test_m, dyn_m, loop=self.loop_metrics(res)), res

    def start_workers(
        self, out_dir: Path, chosen: list[str], resume: bool
    ) -> dict[str, LoopWorker]:
        """One :class:`~protorch.experiments.loop_worker.LoopWorker` per chosen loop baseline when
        the run may use more than one core (:func:`~protorch.threads.core_budget`) on the CPU and
        the experiment's settings can be passed to a process; none otherwise (they run here,
        after the method's loop)."""
        names = [b for b in chosen if b in self.loop_baselines]
        if (
            not names
            or core_budget() < 2
            or torch.device(self.device).type != "cpu"
            or type(self).__module__ == "__main__"
            or "<locals>" in type(self).__qualname__
        ):
            return {}  # (a class a child process cannot import runs its baselines here)
        try:
            encode_settings(self.constructed_with)
        except TypeError:
            return {}
        return {
            b: LoopWorker(self, self.constructed_with, b, out_dir / "baselines" / b, resume)
            for b in names
        }

    def run(
        self,
        out_dir: Path,
        *,
        baselines: Sequence[str] | None = (),
        resume: bool = False,
        progress: bool = False,
        plot: bool = True,
    ) -> dict:
        """Run the experiment into ``out_dir`` (module docstring); return the metrics."""
        t0 = time.perf_counter()
        out_dir = Path(out_dir)
        chosen = self.check_baselines(baselines)
        if not resume:
            self.refuse_finished(out_dir, chosen)
        self.build()
        metrics = self.describe()
        section = (
            metrics.setdefault(self.baseline_section, {}) if self.baseline_section else metrics
        )
        artefacts: dict = {}

        workers = self.start_workers(
            out_dir, chosen, resume
        )  # loop baselines beside the method's loop

        def baseline(name, model):
            t1 = time.perf_counter()
            section[name], artefacts[name] = self.run_baseline(
                name, out_dir, model, resume, progress, workers.get(name)
            )
            self.seconds[name] = round(time.perf_counter() - t1, 3)

        try:
            for name in (b for b in chosen if b in self.pre_loop_baselines):
                baseline(name, None)
            res = self.run_loop(
                run_dir=out_dir,
                resume=resume,
                progress=progress,
                **({"threads": beside_workers(len(workers))} if workers else {}),
            )
            self.seconds["loop"] = round(res.seconds, 3)
            model = load(
                out_dir, device=self.device, dtype=self.dtype
            )  # the checkpoint is what gets evaluated
            t1 = time.perf_counter()
            test_m, dyn_m, episodes = self.evaluate(model)
            self.seconds["evaluation"] = round(time.perf_counter() - t1, 3)
            self.record(metrics, test_m, dyn_m, res)
            metrics.update(self.extra_tests(model))
            for name in (b for b in chosen if b not in self.pre_loop_baselines):
                baseline(name, model)
        finally:  # a failed run ends its workers
            for w in workers.values():
                w.stop()
        if plot:
            t1 = time.perf_counter()
            self.figures(out_dir, Outcome(model, res, episodes, artefacts), metrics)
            self.seconds["figures"] = round(time.perf_counter() - t1, 3)
        self.seconds["total"] = round(time.perf_counter() - t0, 3)
        metrics["seconds"] = self.seconds_metrics()
        return metrics


# ----------------------------------------------------------------------------- module functions
def _settings_parameters(cls: type) -> list[inspect.Parameter]:
    """The keyword parameters of ``cls(...)``: each ``__init__`` along the MRO adds its own
    until one without ``**settings``."""
    params: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        sig = inspect.signature(vars(klass)["__init__"])
        for name, p in sig.parameters.items():
            if name != "self" and p.kind is p.KEYWORD_ONLY:
                params.setdefault(name, p)
        if not any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values()):
            break
    return list(params.values())


def experiment_functions(
    cls: type[SelfImprovementExperiment],
    *,
    baselines: Sequence[str],
    progress: bool,
    run_doc: str,
    threads: bool = False,
) -> tuple[Callable[..., SelfImprovementExperiment], Callable[..., dict]]:
    """An experiment module's ``(prepare, run)`` for ``cls``, written once: ``prepare(**settings)``
    validates every setting (clear errors, before any work) and builds the experiment
    (demonstrations, priors, test environments); ``run(out_dir, **settings, baselines=,
    resume=, progress=, plot=)`` runs it into ``out_dir`` and returns the metrics (``run_doc``:
    its docstring). Both carry the explicit signature of ``cls``'s settings, which the app and
    the benchmarks read. ``threads=True``: ``run`` also takes ``threads`` (torch's intra-op
    threads for the run, restored afterwards; ``None`` keeps the setting around the call)."""
    settings_params = _settings_parameters(cls)

    def prepare(**settings) -> SelfImprovementExperiment:
        return cls(**settings).build()

    def run(
        out_dir: Path,
        *,
        baselines: Sequence[str] = tuple(baselines),
        resume: bool = False,
        progress: bool = progress,
        plot: bool = True,
        threads: int | None = None,
        **settings,
    ) -> dict:
        if threads is not None and (
            isinstance(threads, bool) or int(threads) != threads or int(threads) < 1
        ):
            raise ValueError(f"threads must be None or an int >= 1, got {threads!r}")
        with torch_threads(threads):
            exp = cls(**settings)
            return exp.run(
                out_dir, baselines=baselines, resume=resume, progress=progress, plot=plot
            )

    own = inspect.signature(run).parameters
    run_params = [own["out_dir"], *settings_params] + [
        own[k] for k in ("baselines", "resume", "progress", "plot")
    ]
    if threads:
        run_params.append(own["threads"])
    prepare.__signature__ = inspect.Signature(settings_params, return_annotation=cls)  # type: ignore[attr-defined]
    run.__signature__ = inspect.Signature(run_params, return_annotation=dict)  # type: ignore[attr-defined]
    prepare.__doc__ = (
        "Validate every setting (clear errors, before any work), make the demonstrations (and "
        "priors) and draw the test environments; see :func:`run` for the settings."
    )
    run.__doc__ = run_doc
    for fn in (prepare, run):
        fn.__module__ = cls.__module__
        fn.__qualname__ = fn.__name__
    return prepare, run
