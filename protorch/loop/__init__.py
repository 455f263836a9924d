"""The self-improvement loop (Ewerton et al. 2019, Sec. III): the only place that wires a task,
a ProMP, an optimiser and the environment map together. No Hydra, no particular task.

1. The initial data set holds one weight Gaussian per demonstrated environment
   (:func:`demonstration_dataset`), optionally plus prior-knowledge ProMPs (``origin="prior"``).
2. Repeat until ``num_envs`` environments were tried: choose ``B`` new environments, infer their
   ProMPs with the GP map (Eq. 7, 8), improve them with the optimiser (``B`` problems in one
   batched PRO; ``B = 1`` is the paper's sequential algorithm), add the accepted solutions to the
   data set and to the map. The data set grown is a copy: the caller's is left unchanged.

The environments come from a pool of ``num_envs`` draws of ``task.sample_envs`` fixed by the seed;
``choice="random"`` takes them in draw order, ``choice="nearest"`` takes the untried ones closest
to the known environments first (the authors' curriculum); ``choice="dataset"`` makes the pool
the initial data set's own environments (demonstrations and priors, in data-set order: the
paper's arm loop iterates its initialisation environments). Every step's optimiser seed is a
function of ``(seed, step)``, so a resumed run repeats exactly what an uninterrupted run does.

The task needs ``costs(traj (..., T, D), env (..., E)) -> (..., O)``, ``success(traj, env) ->
(...)`` bool and ``sample_envs(n, generator, dtype=...) -> (n, E)``. Trajectories of ``B``
problems' samples are ``(B, S, T, D)``; the loop passes ``env[:, None]`` so they broadcast.

Multimodal tasks (``labeler=``): a solution is stored with the label the labeller gives its
mean trajectory (e.g. the side it passes an obstacle on, its homotopy class), the map keeps the
labels apart, and a new environment starts from the label whose predicted mean has the lowest
summed task costs (:meth:`~protorch.gp.EnvMap.predict_best`); the held-out check uses the same
label-aware inference. Without a labeller every entry has label 0.

The call is ``self_improve(task, promp, data, optimizer, env_map, settings, run=...)``: the
optimiser an :class:`OptimizerSpec` (class and keyword arguments), the settings one
:class:`LoopSettings` (the app's ``loop`` group is generated from it), the run a :class:`Run`
(folder, resume, progress) or just the folder.

Checkpoints (every ``checkpoint_every`` steps and at the end, atomic): the data set in
``<run_dir>/checkpoint/dataset.safetensors`` via :func:`protorch.data.checkpoint.save_model` (so
:func:`protorch.load` rebuilds the map), with the loop's state (step, environments tried, metrics
rows, elapsed seconds) in the same file's metadata, so data set and state can never disagree;
``<run_dir>/loop_metrics.csv`` is rewritten atomically from those rows at the same moment.
``Run(dir, resume=True)`` reloads that file, rebuilds the map by replaying the same fit and
adds (so it is bit-identical to the killed run's) and continues with the next step: a resumed run
ends with the same data set as an uninterrupted one. The refill loop (:mod:`.refill`) has work in
flight at its checkpoints; each one saves it beside the data set (``inflight-<step>.safetensors``,
:mod:`.inflight`) and a resumed run puts it back, so it too goes on bit for bit. The run's
folder is checked to be writable before any work.

The package: :mod:`.settings` (:class:`LoopSettings`, :class:`OptimizerSpec`, :class:`Run`,
validated), :mod:`.state` (:class:`RunState`:
signature, checkpoint, resume), :mod:`.phases` (choose, infer, optimise, accept),
:mod:`.refill` (the refill loop), :mod:`.inflight` (its work in flight at a checkpoint) and
:mod:`.initial` (the demonstrations' data set); :func:`self_improve` reads as the algorithm above.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from ..data.checkpoint import save_model
from ..data.dataset import TrajectoryDataset
from ..threads import ThreadGovernor, core_budget
from .initial import dataset_pool, demonstration_dataset, group_by_env
from .phases import Evaluator, accept, add, choose, infer, optimise, step_row
from .refill import refill_loop
from .settings import ADD_ONLY, CHOICES, LoopSettings, OptimizerSpec, Run
from .state import (
    LOOP_STATE_VERSION,
    METRIC_FIELDS,
    METRICS_FILE,
    RunState,
    run_signature,
    writable_folder,
)

__all__ = [
    "ADD_ONLY",
    "CHOICES",
    "LOOP_STATE_VERSION",
    "METRICS_FILE",
    "METRIC_FIELDS",
    "LoopResult",
    "LoopSettings",
    "OptimizerSpec",
    "Run",
    "RunState",
    "demonstration_dataset",
    "group_by_env",
    "can_refill",
    "self_improve",
]


@dataclass
class LoopResult:
    """What :func:`self_improve` returns.

    ``metrics`` holds one dict per step (keys :data:`METRIC_FIELDS`; row 0 is the initial data
    set); ``seconds`` the loop's wall time, earlier (resumed) processes included; ``tried`` the
    pool indices of every environment tried, in order; ``resumed_from`` the step the run
    continued after (``None`` for a fresh run).
    """

    dataset: TrajectoryDataset
    env_map: object
    metrics: list[dict]
    seconds: float
    tried: list[int]
    pool: Tensor
    resumed_from: int | None = None

    @property
    def success_rate(self) -> float:
        """Success of the optimised mean trajectories over every environment tried."""
        return float(self.metrics[-1]["success_rate"]) if len(self.metrics) > 1 else float("nan")


def self_improve(
    task,
    promp,
    data: TrajectoryDataset,
    optimizer,
    env_map: Callable[[], object],
    settings: LoopSettings | None = None,
    run: Run | str | Path | None = None,
    *,
    solved: Callable[[Tensor, Tensor], Tensor] | None = None,
    labeler: Callable[[Tensor, Tensor], Tensor] | None = None,
    eval_envs: Tensor | None = None,
    **removed,
) -> LoopResult:
    """Run the self-improvement loop; see the module docstring.

    Args:
        task: costs / success / sample_envs (module docstring); ``task.name`` is recorded. If it
            has ``objective_cost(traj, env, o) -> (...)``, PRO's per-objective steps compute
            only the objective they read.
        promp: the :class:`~protorch.ProMP` of the data set's weights (its basis and device are
            used).
        data: the initial data set (demonstrations, priors), left unchanged: the loop grows a
            copy (``LoopResult.dataset``). On resume the checkpoint's data set replaces it.
        optimizer: the optimiser and its keyword arguments: an :class:`OptimizerSpec`
            (``OptimizerSpec(PRO, {"beta": 20, "max_iter": 50})``), ``functools.partial(PRO,
            beta=20)`` or the class alone (its defaults).
        env_map: a factory returning an empty :class:`~protorch.gp.EnvMap` (its ``backend``,
            ``alpha`` and ``options()`` are saved with the checkpoint).
        settings: a :class:`LoopSettings` (default ``LoopSettings()``): ``num_envs``,
            ``batch_size`` (``B`` environments inferred and optimised at once; the last step
            may be smaller), ``add_only`` (``"converged"``: the optimiser's flag, the authors'
            rule, a ``solved`` stop counting as converged; ``"success"``: the optimised mean
            passes ``task.success``; ``"all"``), ``choice`` (module docstring), ``each_label``
            (with a labeller: optimise every known label's prediction for each environment, ``K
            b`` problems in one batched optimiser, and add every accepted solution, one per
            environment and final label, the cheaper where two ended in the same class; the
            metrics rows then count problems in ``added``, ``converged`` and the iterations, and
            environments in ``initial_success`` / ``success``), ``sample_steps`` (evaluate the
            samples at this many evenly spaced phases instead of the ProMP's ``T``; the final
            solutions are always checked on all ``T`` steps), ``seed`` (the pool and every
            step's optimiser seed), ``min_var`` (floor on the inferred variance the optimiser
            starts from), ``var_floor`` (floor on a new entry's variance, i.e. its GP noise:
            PRO can shrink variances to ~1e-7, which a flat kernel then fits with wild
            functions), ``checkpoint_every``, ``refill`` (keep ``batch_size`` environments in
            flight in one long-lived optimiser, a slot getting the next environment as soon as
            its problems stop, :mod:`.refill`; needs an optimiser that restarts single problems,
            ``can_restart``: PRO with ``relevance_every=1``, RWR, CEM; ``"auto"``: where it
            can), ``refill_group`` (finished environments added and refilled once this many are
            done), ``eval_dtype`` (the optimiser's search distribution, trajectories and costs;
            ``None``: the ProMP's; the data set and map keep their own) and ``threads``
            (torch's intra-op threads for the call, restored after it: an int, ``None`` or
            ``"auto"``, the cores other programs leave free, re-chosen before every step,
            :class:`~protorch.threads.ThreadGovernor`, docs/contention.md).
        run: a :class:`Run` (``dir``, ``resume``, ``progress``, ``desc``, ``on_step``), a run
            folder or ``None`` (no files). A resumed run must be the same run: the same initial
            data set and every setting that changes what the loop computes; otherwise an error
            names what differs. Without ``resume`` an existing checkpoint is an error.
        solved: ``(traj (b, T, D), env (b, E)) -> (b,)`` bool, checked on every active
            problem's mean before the first and after every iteration; a solved problem stops
            there (converged). ``None``: each problem runs until the optimiser's own rule stops.
        labeler: ``(traj (b, T, D), env (b, E)) -> (b,)`` integer label of a solution (module
            docstring). With it, inference (the optimiser's start and ``eval_success``) predicts
            every label's mean and takes the one with the lowest summed ``task.costs``.
        eval_envs: ``(Q, E)`` held-out environments; after every step the map's mean
            trajectories on them are checked with ``task.success`` (``eval_success``).
    """
    if removed:
        raise TypeError(
            f"self_improve() no longer takes {', '.join(f'{k}=' for k in sorted(removed))}: call "
            "self_improve(task, promp, data, OptimizerSpec(PRO, {...}), env_map, "
            "LoopSettings(num_envs=..., ...), run=Run(dir=..., resume=...))"
        )
    settings = LoopSettings() if settings is None else settings
    if not isinstance(settings, LoopSettings):
        raise TypeError(f"settings must be a LoopSettings, got {type(settings).__name__}")
    spec, run = OptimizerSpec.of(optimizer), Run.of(run)
    _check_inputs(data, spec, labeler, settings)
    if settings.refill == "auto":  # on where the optimiser can restart single problems
        settings = settings.replace(refill=can_refill(spec))
    with ThreadGovernor(settings.threads) as governor:
        return _improve(
            task,
            promp,
            data,
            spec,
            env_map,
            settings,
            run,
            solved=solved,
            labeler=labeler,
            eval_envs=eval_envs,
            governor=governor,
        )


def _improve(
    task,
    promp,
    dataset: TrajectoryDataset,
    spec: OptimizerSpec,
    env_map: Callable[[], object],
    settings: LoopSettings,
    run: Run,
    *,
    solved,
    labeler,
    eval_envs,
    governor,
) -> LoopResult:
    """The body of :func:`self_improve` (its arguments, checked), run inside its thread
    setting."""
    optimizer, optimizer_kwargs, on_step = spec.cls, spec.kwargs, run.on_step
    run_dir = None if run.dir is None else writable_folder(run.dir)
    ev = Evaluator.build(
        task,
        promp,
        eval_dtype=settings.torch_eval_dtype,
        sample_steps=settings.sample_steps,
        labeler=labeler,
        dtype=dataset.dtype,
    )
    gp = env_map()
    state = RunState(
        run_signature(
            settings,
            optimizer,
            optimizer_kwargs,
            gp,
            ev.eval_dtype,
            solved=solved is not None,
            labels=labeler is not None,
        ),
        run_dir,
        save=save_model,
    )
    # the pool of environments, fixed by the seed (drawn on the CPU)
    if settings.choice == "dataset":
        pool = dataset_pool(dataset, settings.num_envs, dataset.dtype)  # (n, E)
    else:
        pool = task.sample_envs(
            settings.num_envs,
            torch.Generator().manual_seed(int(settings.seed)),
            dtype=dataset.dtype,
        )  # (n, E)
    if eval_envs is not None:
        eval_envs = ev.here(torch.as_tensor(eval_envs))  # (Q, E)
    data = state.start(dataset, promp, resume=run.resume)  # a copy of dataset, or the checkpoint's
    state.fit(gp, data)
    if not state.rows:
        state.rows.append(
            {
                "step": 0,
                "envs_done": 0,
                "dataset_size": len(data),
                "eval_success": ev.eval_success(gp, eval_envs),
                "seconds": 0.0,
            }
        )
    bar = _progress_bar(run.progress, settings.num_envs, len(state.tried), run.desc)

    def finish_step(row: dict) -> None:
        """Complete a refill loop's metrics row, checkpoint and report it."""
        governor.step()
        state.step += 1
        row.update(
            step=state.step,
            envs_done=len(state.tried),
            dataset_size=len(data),
            eval_success=ev.eval_success(gp, eval_envs),
            success_rate=round((state.successes + row["success"]) / len(state.tried), 6),
            seconds=round(state.elapsed(), 3),
        )
        state.rows.append(row)
        if settings.is_checkpoint_step(state.step) or len(state.tried) == settings.num_envs:
            state.checkpoint(data, gp)
        _show(bar, row, state.successes / len(state.tried), len(data))
        if on_step is not None:
            on_step(row)

    if settings.refill:
        labels = (
            torch.unique(gp.labels).cpu() if settings.each_label else None
        )  # (K,) fixed for the run
        refill_loop(
            ev=ev,
            gp=gp,
            data=data,
            pool=pool,
            state=state,
            settings=settings,
            optimizer=optimizer,
            optimizer_kwargs=optimizer_kwargs,
            solved=solved,
            labels=labels,
            finish_step=finish_step,
        )
    while not settings.refill and state.step < settings.num_steps:
        governor.step()  # "auto": the cores other programs leave free now
        state.step += 1
        pick = choose(pool, state.tried, data.env, settings.batch_size, settings.choice)  # (b,)
        problems = infer(
            ev, gp, pool[pick], each_label=settings.each_label, min_var=settings.min_var
        )
        opt = optimizer(
            problems.mu, problems.var, seed=settings.step_seed(state.step), **optimizer_kwargs
        )
        if torch.get_num_threads() < core_budget() and callable(getattr(opt, "draw_ahead", None)):
            # a free core makes the next ask's noise while this one's costs are computed
            opt.draw_ahead()
        res = optimise(ev, problems, opt, solved)
        solutions = accept(ev, problems, res, settings)
        add(data, gp, problems.env, solutions)
        state.tried.extend(pick.tolist())
        row = step_row(state.step, len(state.tried), len(data), problems, res, solutions)
        row.update(
            eval_success=ev.eval_success(gp, eval_envs),
            success_rate=round((state.successes + row["success"]) / len(state.tried), 6),
            seconds=round(state.elapsed(), 3),
        )
        state.rows.append(row)
        if settings.is_checkpoint_step(state.step):
            state.checkpoint(data, gp)
        _show(bar, row, state.successes / len(state.tried), len(data))
        if on_step is not None:
            on_step(row)
    if bar is not None:
        bar.close()
    if (
        run_dir is not None and not state.checkpoint_file.is_file()
    ):  # num_envs = 0: still a loadable checkpoint
        state.checkpoint(data, gp)
    return LoopResult(
        dataset=data,
        env_map=gp,
        metrics=state.rows,
        seconds=state.elapsed(),
        tried=state.tried,
        pool=pool,
        resumed_from=state.resumed_from,
    )


def _check_inputs(dataset, spec: OptimizerSpec, labeler, settings: LoopSettings) -> None:
    """Refuse, before any work, what :class:`LoopSettings` cannot see."""
    if settings.each_label and labeler is None:
        raise ValueError("each_label=True needs a labeler")
    if len(dataset) == 0:
        raise ValueError("the initial data set is empty: add demonstrations or priors first")
    if settings.refill is True and not can_refill(spec):
        raise ValueError(
            "refill=True needs an optimiser that restarts single problems (PRO with "
            "relevance_every=1, "
            f"RWR, CEM); {spec.cls.__name__} with these settings cannot: set refill=False"
        )


def can_refill(optimizer, optimizer_kwargs: dict | None = None) -> bool:
    """Whether the optimiser (an :class:`OptimizerSpec`, a class with ``optimizer_kwargs``, or a
    partial) can restart single problems (``can_restart``), asked of one built on a small
    problem."""
    spec = OptimizerSpec.of(optimizer)
    kw = {**spec.kwargs, **(optimizer_kwargs or {})}
    kw.pop("seed", None)
    if getattr(spec.cls, "can_restart", False) is False:
        return False
    return bool(spec.cls(torch.zeros(1, 2), torch.ones(1, 2), seed=0, **kw).can_restart)


def _progress_bar(enabled: bool, total: int, initial: int, desc: str):
    """A tqdm bar over the environments (``None`` unless ``enabled``)."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="env", dynamic_ncols=True)


def _show(bar, row: dict, success_rate: float, dataset_size: int) -> None:
    """Advance the bar by the step's environments, with the live success rate."""
    if bar is None:
        return
    bar.update(row["batch"])
    post = {"success": f"{success_rate:.3f}", "data": dataset_size}
    if row["eval_success"] is not None:
        post["eval"] = f"{row['eval_success']:.3f}"
    bar.set_postfix(post)
