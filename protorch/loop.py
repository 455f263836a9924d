"""The self-improvement loop (Ewerton et al. 2019, Sec. III): the only place that wires a task,
a ProMP, an optimiser and the environment map together. No Hydra, no particular task.

1. The initial data set holds one weight Gaussian per demonstrated environment
   (:func:`demonstration_dataset`), optionally plus prior-knowledge ProMPs (``origin="prior"``).
2. Repeat until ``num_envs`` environments were tried: choose ``B`` new environments, infer their
   ProMPs with the GP map (Eq. 7, 8), improve them with the optimiser (``B`` problems in one
   batched PRO; ``B = 1`` is the paper's sequential algorithm), add the accepted solutions to the
   data set and to the map.

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
label-aware inference. Without a labeller everything is label 0, as before.

Checkpoints (every ``checkpoint_every`` steps and at the end, atomic): the data set in
``<run_dir>/checkpoint/dataset.safetensors`` via :func:`protorch.data.checkpoint.save_model` (so
:func:`protorch.load` rebuilds the map), with the loop's state (step, environments tried, metrics
rows, elapsed seconds) in the same file's metadata, so data set and state can never disagree;
``<run_dir>/loop_metrics.csv`` is rewritten atomically from those rows at the same moment.
``resume=True`` reloads that file, rebuilds the map by replaying the same fit and adds (so it is
bit-identical to the killed run's) and continues with the next step: a resumed run ends with the
same data set as an uninterrupted one.
"""

from __future__ import annotations

import copy
import csv
import io
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import torch
from torch import Tensor

from .data.checkpoint import checkpoint_path, save_model
from .data.dataset import TrajectoryDataset
from .data.files import atomic_write_bytes

__all__ = ["LoopResult", "self_improve", "demonstration_dataset", "group_by_env", "ADD_ONLY", "CHOICES",
           "METRIC_FIELDS", "LOOP_STATE_VERSION"]

ADD_ONLY = ("converged", "success", "all")
CHOICES = ("random", "nearest", "dataset")
LOOP_STATE_VERSION = 1
METRICS_FILE = "loop_metrics.csv"
# one row per step (step 0: the initial data set, before any environment was tried)
METRIC_FIELDS = (
    "step", "envs_done", "dataset_size", "batch", "added", "initial_success", "success", "converged",
    "iterations_mean", "iterations_max", "eval_success", "success_rate", "seconds",
)


# ----------------------------------------------------------------------------- initial data
def group_by_env(envs: Tensor) -> list[Tensor]:
    """Indices of the rows of ``envs (n, E)`` grouped by identical environment, in order of first
    appearance: a list of ``(n_g,)`` long tensors."""
    uniq, inverse = torch.unique(envs, dim=0, return_inverse=True)  # (G, E), (n,)
    first = torch.full((uniq.shape[0],), envs.shape[0], dtype=torch.long)
    first = first.scatter_reduce(0, inverse, torch.arange(envs.shape[0]), reduce="amin")  # (G,)
    order = torch.argsort(first)
    return [torch.nonzero(inverse == g).flatten() for g in order.tolist()]


def demonstration_dataset(
    promp, demos: Sequence[Tensor], demo_envs: Tensor, *, task_name: str = "", var_floor: float = 0.0,
    dtype: torch.dtype = torch.float64, labels: Tensor | None = None,
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
    """
    demo_envs = torch.as_tensor(demo_envs)
    if demo_envs.ndim != 2 or demo_envs.shape[0] != len(demos):
        raise ValueError(f"demo_envs must be ({len(demos)}, E), got {tuple(demo_envs.shape)}")
    if not var_floor >= 0:
        raise ValueError(f"var_floor must be >= 0, got {var_floor}")
    lab = torch.zeros(len(demos), dtype=torch.long) if labels is None else torch.as_tensor(labels).cpu()
    if lab.shape != (len(demos),) or lab.is_floating_point() or lab.dtype == torch.bool:
        raise ValueError(f"labels must be ({len(demos)},) integers, got {labels!r}")
    w = promp.weights(demos).to(dtype).cpu()  # (n, N)
    demo_envs = demo_envs.cpu()
    ds = TrajectoryDataset(promp, demo_envs.shape[1], task_name=task_name, dtype=dtype)
    keyed = demo_envs if labels is None else torch.cat([demo_envs.to(dtype), lab[:, None].to(dtype)], 1)
    for idx in group_by_env(keyed):
        if idx.numel() < 2:
            raise ValueError(
                f"environment {demo_envs[idx[0]].tolist()} (label {int(lab[idx[0]])}) has 1 demonstration; "
                "a weight variance needs >= 2"
            )
        wg = w[idx]  # (n_g, N)
        var = (wg - wg.mean(0)).pow(2).mean(0).clamp_min(var_floor)  # (N,)
        ds.append(demo_envs[idx[0]].to(dtype), wg.mean(0), var, label=int(lab[idx[0]]), origin="demonstration",
                  converged=True)
    return ds


# ----------------------------------------------------------------------------- the loop
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


def _step_seed(seed: int, step: int) -> int:
    return (int(seed) * 1_000_003 + int(step) * 7_919 + 17) % (2**63 - 1)


def _write_metrics_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRIC_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in METRIC_FIELDS})
    atomic_write_bytes(path, buf.getvalue().encode())


def _check_options(num_envs, batch_size, add_only, choice, checkpoint_every) -> None:
    for name, v, lo in (("num_envs", num_envs, 0), ("batch_size", batch_size, 1),
                        ("checkpoint_every", checkpoint_every, 1)):
        if isinstance(v, bool) or int(v) != v or int(v) < lo:
            raise ValueError(f"{name} must be an int >= {lo}, got {v!r}")
    if add_only not in ADD_ONLY:
        raise ValueError(f"add_only must be one of {ADD_ONLY}, got {add_only!r}")
    if choice not in CHOICES:
        raise ValueError(f"choice must be one of {CHOICES}, got {choice!r}")


def _jsonable(x):
    """Settings as the JSON of the checkpoint holds them (tuples as lists, other objects by repr)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in sorted(x.items())}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if x is None or isinstance(x, (bool, int, str)):
        return x
    if isinstance(x, float):
        return x if math.isfinite(x) else repr(x)
    if isinstance(x, Tensor) and x.numel() == 1:
        return _jsonable(x.item())
    return repr(x)


def _same_data(given: TrajectoryDataset, saved: TrajectoryDataset, n: int) -> bool:
    """Whether ``given`` is the first ``n`` entries of ``saved`` (up to round-off)."""
    if len(given) != n or len(saved) < n:
        return False
    pairs = ((given.env, saved.env[:n]), (given.mean, saved.mean[:n]), (given.var, saved.var[:n]))
    return all(a.shape == b.shape and torch.allclose(a, b.to(a), rtol=1e-6, atol=1e-9) for a, b in pairs) \
        and torch.equal(given.label, saved.label[:n].to(given.label))


def self_improve(
    task,
    promp,
    dataset: TrajectoryDataset,
    *,
    optimizer: type,
    optimizer_kwargs: dict,
    env_map: Callable[[], object],
    num_envs: int,
    batch_size: int = 1,
    add_only: str = "success",
    choice: str = "random",
    solved: Callable[[Tensor, Tensor], Tensor] | None = None,
    labeler: Callable[[Tensor, Tensor], Tensor] | None = None,
    each_label: bool = False,
    sample_steps: int | None = None,
    seed: int = 0,
    eval_envs: Tensor | None = None,
    min_var: float = 0.0,
    var_floor: float = 0.0,
    eval_dtype: torch.dtype | None = None,
    run_dir: str | Path | None = None,
    checkpoint_every: int = 1,
    resume: bool = False,
    progress: bool = False,
    desc: str = "self-improvement",
    on_step: Callable[[dict], None] | None = None,
) -> LoopResult:
    """Run the self-improvement loop; see the module docstring.

    Args:
        task: costs / success / sample_envs (module docstring); ``task.name`` is recorded. If it
            has ``objective_cost(traj, env, o) -> (...)``, PRO's per-objective steps compute
            only the objective they read.
        promp: the :class:`~protorch.ProMP` of the data set's weights (its basis and device are
            used).
        dataset: the initial data (demonstrations, priors); grown in place by accepted solutions.
            On ``resume`` the checkpoint's data set replaces it.
        optimizer, optimizer_kwargs: the optimiser class (``PRO``, ``RWR``, ...) and its keyword
            arguments (``beta``, ``num_samples``, ``max_iter``, ``tol``, ...; not ``seed``).
        env_map: a factory returning an empty :class:`~protorch.gp.EnvMap` (its ``backend``,
            ``alpha`` and ``options()`` are saved with the checkpoint).
        num_envs: environments to try; ``batch_size``: ``B`` tried (inferred and optimised) at
            once; the last step may be smaller.
        add_only: which solutions join the data set: ``"converged"`` (the optimiser's flag, the
            authors' rule; a ``solved`` stop counts as converged), ``"success"`` (the optimised
            mean trajectory passes ``task.success``) or ``"all"``.
        choice: ``"random"``, ``"nearest"`` or ``"dataset"`` (module docstring).
        solved: ``(traj (b, T, D), env (b, E)) -> (b,)`` bool, checked on every active problem's
            mean before the first and after every iteration; a solved problem stops there
            (converged). ``None``: run each problem until the optimiser's own rule stops it.
        labeler: ``(traj (b, T, D), env (b, E)) -> (b,)`` integer label of a solution (module
            docstring). With it, inference (the optimiser's start and ``eval_success``) predicts
            every label's mean and takes the one with the lowest summed ``task.costs``.
        each_label: with a labeller, optimise every known label's prediction for each chosen
            environment (``K b`` problems in one batched optimiser) and add every accepted
            solution (one per environment and final label: two problems that ended in the same
            class keep the cheaper), so each class is learned everywhere, not only where it is
            the better one.
            The metrics rows then count problems in ``added``, ``converged`` and the iterations,
            and environments in ``initial_success`` / ``success`` (the lowest-cost class's mean,
            as the label-aware inference would choose it).
        sample_steps: evaluate the optimiser's sampled trajectories at this many evenly spaced
            phases instead of the ProMP's ``T`` (a task whose costs use fewer steps than ``T``
            pays for those only); the final solutions are always checked on all ``T`` steps.
        seed: fixes the pool of environments and every step's optimiser seed.
        eval_envs: ``(Q, E)`` held-out environments; after every step the map's mean
            trajectories on them are checked with ``task.success`` (``eval_success``).
        min_var: floor on the inferred variance the optimiser starts from.
        var_floor: floor on the variance stored with a new entry, i.e. on its GP noise. PRO can
            shrink variances to ~1e-7; the GP then treats solutions as exact and, with a flat
            kernel, fits their small inconsistencies with wild functions (see the README).
        eval_dtype: dtype of the optimiser's search distribution, the trajectories and the costs
            (float32 is about 3x faster on a CPU); default the ProMP's. The data set and the map
            keep their own dtype.
        run_dir: where the checkpoint and ``loop_metrics.csv`` go (``None``: no files).
        checkpoint_every: write the checkpoint every k steps (and after the last).
        resume: continue from ``run_dir``'s checkpoint if there is one. It must be the same run:
            the same initial data set and every setting that changes what the loop computes
            (``num_envs``, ``batch_size``, ``seed``, ``choice``, ``add_only``, the optimiser and
            its kwargs, the map's backend, alpha and options, ``min_var``, ``var_floor``,
            ``sample_steps``, ``eval_dtype``, labels); otherwise an error names what differs.
            Without ``resume`` an existing checkpoint there is an error (never overwritten).
        progress: show a tqdm bar with the live success rate.
        on_step: called with each new metrics row (after the step's checkpoint, if any).
    """
    _check_options(num_envs, batch_size, add_only, choice, checkpoint_every)
    num_envs, batch_size, checkpoint_every = int(num_envs), int(batch_size), int(checkpoint_every)
    for name, v in (("min_var", min_var), ("var_floor", var_floor)):
        if not float(v) >= 0:
            raise ValueError(f"{name} must be >= 0, got {v}")
    if each_label and labeler is None:
        raise ValueError("each_label=True needs a labeler")
    if sample_steps is not None and (isinstance(sample_steps, bool) or int(sample_steps) != sample_steps
                                     or int(sample_steps) < 2):
        raise ValueError(f"sample_steps must be None or an int >= 2, got {sample_steps!r}")
    if "seed" in optimizer_kwargs:
        raise ValueError("optimizer_kwargs must not hold 'seed': the loop seeds every step from (seed, step)")
    if len(dataset) == 0:
        raise ValueError("the initial data set is empty: add demonstrations or priors first")
    run_dir = None if run_dir is None else Path(run_dir)
    if resume and run_dir is None:
        raise ValueError("resume=True needs a run_dir")
    dtype, device = dataset.dtype, promp.basis.device
    eval_dtype = eval_dtype or promp.basis.dtype
    promp_eval = copy.deepcopy(promp).to(eval_dtype)
    promp_sample = promp_eval if sample_steps is None else type(promp)(
        promp.num_dof, promp.num_basis, int(sample_steps), width=promp.width, ridge=promp.ridge, dtype=eval_dtype,
        device=device)  # the same basis functions on a coarser time grid
    one_cost = getattr(task, "objective_cost", None)  # optional: one objective alone, (...)
    gp = env_map()
    # every setting that changes what the loop computes: a resumed run must be the same run
    signature = {"num_envs": num_envs, "batch_size": batch_size, "seed": int(seed), "choice": choice,
                 "add_only": add_only, "optimizer": optimizer.__name__,
                 "optimizer_kwargs": _jsonable(optimizer_kwargs),
                 "env_map": _jsonable({"backend": gp.backend, "alpha": gp.alpha, **gp.options()}),
                 "min_var": float(min_var), "var_floor": float(var_floor), "sample_steps": sample_steps,
                 "eval_dtype": str(eval_dtype), "solved": solved is not None}
    if labeler is not None:
        signature["labels"] = True
    if each_label:
        signature["each_label"] = True

    # the pool of environments, fixed by the seed (drawn on the CPU)
    if choice == "dataset":
        pool = _dataset_pool(dataset, num_envs, dtype)  # (num_envs, E)
    else:
        pool = task.sample_envs(num_envs, torch.Generator().manual_seed(int(seed)), dtype=dtype)  # (num_envs, E)
    if eval_envs is not None:
        eval_envs = torch.as_tensor(eval_envs).to(dtype=eval_dtype, device=device)  # (Q, E)

    # state: fresh, or from the checkpoint
    tried: list[int] = []
    rows: list[dict] = []
    seconds_before, step, resumed_from = 0.0, 0, None
    ckpt = None if run_dir is None else checkpoint_path(run_dir)
    if ckpt is not None and ckpt.is_file():
        if not resume:
            raise FileExistsError(
                f"{ckpt} already exists: pass resume=True to continue that run, or choose another run directory"
            )
        loaded = TrajectoryDataset.load(ckpt, promp=promp, task_name=dataset.task_name)
        state = loaded.metadata.get("loop")
        if not state or state.get("version") != LOOP_STATE_VERSION:
            raise ValueError(f"{ckpt} holds no loop state this protorch can resume from")
        if state["signature"] != signature:
            diff = {k: (state["signature"].get(k), signature.get(k)) for k in {**state["signature"], **signature}
                    if state["signature"].get(k) != signature.get(k)}
            raise ValueError(f"cannot resume {ckpt}: it was started with other settings, (saved, now): {diff}")
        initial = int(state["rows"][0]["dataset_size"]) if state["rows"] else 0
        if not _same_data(dataset, loaded, initial):
            raise ValueError(
                f"cannot resume {ckpt}: its initial data set ({initial} entries) is not the one given now "
                f"({len(dataset)} entries); were the demonstrations or priors changed?"
            )
        dataset = loaded
        tried, rows = list(state["tried"]), list(state["rows"])
        seconds_before, step = float(state["seconds"]), int(state["step"])
        resumed_from = step

    t_start = time.perf_counter()
    if rows:  # resumed: replay the fit and the per-step adds, so the map is bit-identical to the
        # one the killed run had (a single refit differs in round-off, and PRO amplifies that)
        sizes = [int(rows[0]["dataset_size"])] + [int(r.get("added") or 0) for r in rows[1:]]
        if sum(sizes) != len(dataset):
            raise ValueError(f"{ckpt}: the loop state does not match its data set ({sum(sizes)} != {len(dataset)})")
        at = 0
        for k, n in enumerate(sizes):
            if n:
                sl = slice(at, at + n)
                args = (dataset.env[sl], dataset.mean[sl], dataset.var[sl], dataset.label[sl])
                if k == 0:
                    gp.fit(*args)
                else:
                    gp.add(*args)
            at += n
    else:
        gp.fit(dataset.env, dataset.mean, dataset.var, dataset.label)

    def score(mu_k: Tensor, env_k: Tensor) -> Tensor:  # (K b, N), (K b, E) -> (K b,) summed costs of the means
        traj = promp_eval.trajectory(mu_k.to(dtype=eval_dtype, device=device))  # (K b, T, D)
        return task.costs(traj, env_k.to(dtype=eval_dtype, device=device)).sum(-1)

    def infer(env_q: Tensor, need_var: bool = True) -> tuple[Tensor, Tensor | None]:
        """Eq. 7, 8 at ``env_q (b, E)``; with a labeller, the best label's prediction."""
        if labeler is not None:
            best = gp.predict_best(env_q, score, need_var=need_var)
            return best.mean, best.var
        if need_var:
            return gp.predict(env_q)
        return gp.predict_mean(env_q), None

    def eval_success() -> float | None:
        if eval_envs is None:
            return None
        mu_q = infer(eval_envs, need_var=False)[0].to(dtype=eval_dtype, device=device)  # (Q, N)
        return round(float(task.success(promp_eval.trajectory(mu_q), eval_envs).double().mean()), 6)

    def elapsed() -> float:
        return seconds_before + time.perf_counter() - t_start

    def checkpoint() -> None:
        if run_dir is None:
            return
        dataset.metadata["loop"] = {"version": LOOP_STATE_VERSION, "signature": signature, "step": step,
                                    "tried": tried, "rows": rows, "seconds": round(elapsed(), 3)}
        save_model(run_dir, dataset, backend=gp.backend, alpha=gp.alpha, include_unconverged=True,
                   **gp.options())
        _write_metrics_csv(run_dir / METRICS_FILE, rows)

    if not rows:
        rows.append({"step": 0, "envs_done": 0, "dataset_size": len(dataset), "eval_success": eval_success(),
                     "seconds": 0.0})
    num_steps = math.ceil(num_envs / batch_size)
    successes = sum(int(r.get("success") or 0) for r in rows)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=num_envs, initial=len(tried), desc=desc, unit="env", dynamic_ncols=True)

    while step < num_steps:
        step += 1
        # ---- 1. choose B untried environments of the pool
        untried = torch.ones(num_envs, dtype=torch.bool)
        untried[tried] = False
        cand = torch.nonzero(untried).flatten()  # (C,)
        b = min(batch_size, cand.numel())
        if choice == "nearest":  # closest to any known environment first (stable: ties by draw order)
            d2 = torch.cdist(pool[cand], dataset.env.to(dtype)).amin(1)  # (C,)
            pick = cand[torch.sort(d2, stable=True).indices[:b]]
        else:
            pick = cand[:b]
        env = pool[pick]  # (b, E) CPU, the data set's dtype
        # ---- 2. infer their ProMPs with the GPs (Eq. 7, 8): one problem per environment, or with
        # each_label one per (label, environment), label-major
        if each_label:
            labs = torch.unique(gp.labels).cpu()  # (K,)
            k = labs.numel()
            env = env.repeat(k, 1)  # (P, E), P = K b
            mu, var = gp.predict(env, labels=labs.repeat_interleave(b).to(gp.labels.device))
        else:
            k = 1
            mu, var = infer(env)  # (b, N), (b, N)
        env_e = env.to(dtype=eval_dtype, device=device)  # (P, E)
        mu = mu.to(dtype=eval_dtype, device=device)  # (P, N)
        var = var.to(dtype=eval_dtype, device=device).clamp_min(min_var)  # (P, N)
        mean_traj = promp_eval.trajectory(mu)  # (P, T, D)
        initial_success = task.success(mean_traj, env_e)  # (P,)
        if k > 1:  # per environment: the class the label-aware inference would start from
            initial_success = _per_env(initial_success, task.costs(mean_traj, env_e).sum(-1), k)
        # ---- 3. improve them: one batched optimiser over the b problems
        opt = optimizer(mu, var, seed=_step_seed(seed, step), **optimizer_kwargs)
        if solved is not None:
            opt.mark_converged(solved(mean_traj, env_e))
        while not opt.stop():
            it = opt.iteration
            w = opt.ask()  # (b, S, N)
            active = opt.active  # (b,) only these are evaluated; the others' costs are never read
            o = getattr(opt, "asked_objective", None)
            if bool(active.any()):
                traj = promp_sample.trajectory(w[active])  # (a, S, T, D)
                if o is not None and one_cost is not None:  # the update reads objective o only
                    costs = w.new_zeros(*w.shape[:2], opt.num_objectives)  # (b, S, O)
                    costs[active, :, o] = one_cost(traj, env_e[active][:, None], o).to(w.dtype)
                else:
                    c = task.costs(traj, env_e[active][:, None]).to(w.dtype)  # (a, S, O)
                    costs = c.new_zeros(*w.shape[:2], c.shape[-1])  # (b, S, O)
                    costs[active] = c
            else:
                costs = w.new_zeros(*w.shape[:2], opt.num_objectives or 1)  # (b, S, O)
            opt.tell(costs)
            if solved is not None and opt.iteration != it and bool(opt.active.any()):
                act = opt.active
                done = torch.zeros_like(act)
                done[act] = solved(promp_eval.trajectory(opt.mean[act]), env_e[act])
                opt.mark_converged(done)
        res = opt.result()
        final_traj = promp_eval.trajectory(res.mean)  # (b, T, D)
        success = task.success(final_traj, env_e).cpu()  # (b,)
        converged = res.converged.cpu()  # (b,)
        cost = task.costs(final_traj, env_e).sum(-1).to(device="cpu", dtype=dtype)  # (b,)
        # ---- 4. add the accepted solutions to the data set and the map
        accept = {"converged": converged, "success": success, "all": torch.ones_like(success)}[add_only]
        new_mean = res.mean.to(device="cpu", dtype=dtype)  # (P, N)
        new_var = res.var.to(device="cpu", dtype=dtype).clamp_min(var_floor)  # (P, N) GP noise
        label = (torch.zeros(accept.shape[0], dtype=torch.long) if labeler is None
                 else torch.as_tensor(labeler(final_traj, env_e)).to(device="cpu", dtype=torch.long))  # (P,)
        if k > 1:  # two problems of one environment that ended in the same class: keep the cheaper
            accept = _one_per_class(accept, label, cost, k)
        if bool(accept.any()):
            dataset.append(env[accept], new_mean[accept], new_var[accept], label=label[accept], origin="learned",
                           converged=converged[accept], cost=cost[accept])
            gp.add(env[accept], new_mean[accept], new_var[accept], label[accept])
        tried.extend(pick.tolist())
        if k > 1:
            success = _per_env(success, cost, k)  # (b,) the lowest-cost class's solution
        successes += int(success.sum())
        iters = _iterations_per_problem(res, mu)
        rows.append({
            "step": step, "envs_done": len(tried), "dataset_size": len(dataset), "batch": b,
            "added": int(accept.sum()), "initial_success": int(initial_success.sum()),
            "success": int(success.sum()), "converged": int(converged.sum()),
            "iterations_mean": round(float(iters.double().mean()), 3), "iterations_max": int(iters.max()),
            "eval_success": eval_success(), "success_rate": round(successes / len(tried), 6),
            "seconds": round(elapsed(), 3),
        })
        if step % checkpoint_every == 0 or step == num_steps:
            checkpoint()
        if bar is not None:
            bar.update(b)
            post = {"success": f"{successes / len(tried):.3f}", "data": len(dataset)}
            if rows[-1]["eval_success"] is not None:
                post["eval"] = f"{rows[-1]['eval_success']:.3f}"
            bar.set_postfix(post)
        if on_step is not None:
            on_step(rows[-1])
    if bar is not None:
        bar.close()
    if run_dir is not None and not ckpt.is_file():  # num_envs = 0: still leave a loadable checkpoint
        checkpoint()
    return LoopResult(dataset=dataset, env_map=gp, metrics=rows, seconds=elapsed(), tried=tried, pool=pool,
                      resumed_from=resumed_from)


def _dataset_pool(dataset: TrajectoryDataset, num_envs: int, dtype) -> Tensor:
    """The first ``num_envs`` distinct environments of the data set, in order: ``(num_envs, E)``."""
    env = dataset.env.to(dtype).cpu()  # (M, E)
    first = torch.stack([g[0] for g in group_by_env(env)]) if env.shape[0] else torch.zeros(0, dtype=torch.long)
    if first.numel() < num_envs:
        raise ValueError(f"choice='dataset' needs num_envs <= the data set's {first.numel()} distinct "
                         f"environments, got num_envs={num_envs}")
    return env[first[:num_envs]]


def _one_per_class(accept: Tensor, label: Tensor, cost: Tensor, k: int) -> Tensor:
    """``accept (K b,)`` of label-major problems, keeping at most one accepted solution per
    environment and final label (the lowest-cost one; ``label``, ``cost (K b,)``)."""
    b = accept.shape[0] // k
    acc, lab, c = accept.reshape(k, b).clone(), label.reshape(k, b), cost.reshape(k, b)
    for i in range(k):
        for j in range(i + 1, k):
            dup = acc[i] & acc[j] & (lab[i] == lab[j])  # (b,)
            drop_j = dup & (c[j] >= c[i])
            acc[j] &= ~drop_j
            acc[i] &= ~(dup & ~drop_j)
    return acc.reshape(-1)


def _per_env(flag: Tensor, cost: Tensor, k: int) -> Tensor:
    """``flag (K b,)`` of label-major problems -> ``(b,)``: the flag of each environment's
    lowest-cost problem (``cost (K b,)``)."""
    b = flag.shape[0] // k
    best = cost.reshape(k, b).argmin(0).to(flag.device)  # (b,)
    return flag.reshape(k, b)[best, torch.arange(b, device=flag.device)]


def _iterations_per_problem(res, mean0: Tensor) -> Tensor:
    """Iterations each problem ran before it stopped moving: ``(B,)`` long. A converged problem's
    mean no longer changes, so this is the last iteration whose mean differs from the one before
    (``mean0 (B, N)``: the start)."""
    hist = res.history.get("mean")
    if hist is None or hist.shape[0] == 0:
        return torch.zeros(mean0.shape[0], dtype=torch.long)
    prev = torch.cat([mean0[None].to(hist), hist[:-1]])  # (I, B, N)
    moved = (hist != prev).any(-1).cpu()  # (I, B)
    it = torch.arange(1, hist.shape[0] + 1)[:, None].expand_as(moved)  # (I, B)
    return torch.where(moved, it, torch.zeros_like(it)).amax(0)  # (B,)
