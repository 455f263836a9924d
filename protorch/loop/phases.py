"""The phases of one step of the self-improvement loop: :func:`choose` the next environments,
:func:`infer` their ProMPs with the GP map (Eq. 7, 8), :func:`optimise` them in one batched
optimiser, :func:`accept` the solutions and :func:`add` them to the data set and the map.

:class:`Evaluator` holds what turns weights into trajectories and costs: the task, the ProMP in
the evaluation dtype (and on a coarser time grid for the optimiser's samples, if asked), and the
optional labeller.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from ..data.dataset import TrajectoryDataset
from ..threads import one_thread
from .settings import LoopSettings

__all__ = [
    "Evaluator",
    "Problems",
    "Solutions",
    "accept",
    "add",
    "choose",
    "infer",
    "optimise",
    "step_row",
]


@dataclass(frozen=True)
class Evaluator:
    """Trajectories and costs of weights: ``task`` (costs / success / optional ``objective_cost``),
    ``promp`` (the evaluation dtype, on the ProMP's device), ``promp_sample`` (the same basis on
    the optimiser's time grid), ``labeler`` (or ``None``) and ``dtype`` (the data set's)."""

    task: object
    promp: object
    promp_sample: object
    labeler: Callable[[Tensor, Tensor], Tensor] | None
    dtype: torch.dtype

    @classmethod
    def build(
        cls,
        task,
        promp,
        *,
        eval_dtype: torch.dtype | None,
        sample_steps: int | None,
        labeler,
        dtype: torch.dtype,
    ) -> Evaluator:
        """From the data set's ProMP: a copy in ``eval_dtype`` (default the ProMP's), and one on
        ``sample_steps`` evenly spaced phases (``None``: the same ``T``)."""
        eval_dtype = eval_dtype or promp.basis.dtype
        promp_eval = copy.deepcopy(promp).to(eval_dtype)
        promp_sample = (
            promp_eval
            if sample_steps is None
            else type(promp)(
                promp.num_dof,
                promp.num_basis,
                int(sample_steps),
                width=promp.width,
                ridge=promp.ridge,
                dtype=eval_dtype,
                device=promp.basis.device,
            )
        )  # the same basis functions on a coarser time grid
        return cls(task, promp_eval, promp_sample, labeler, dtype)

    @property
    def eval_dtype(self) -> torch.dtype:
        return self.promp.basis.dtype

    @property
    def device(self) -> torch.device:
        return self.promp.basis.device

    def sample_trajectory(self, w: Tensor, steps: tuple[int, ...] | None = None) -> Tensor:
        """The optimiser's samples ``w (..., N)`` as trajectories on the sample grid ``(..., T,
        D)``,
        or at the time indices ``steps`` only ``(..., len(steps), D)``. Those rows are taken with
        zero rows up to 16: a BLAS product of two rows takes another code path whose rounding
        differs in the last bit, so padding keeps every number equal to the full trajectory's."""
        if steps is None:
            return self.promp_sample.trajectory(w)
        basis = self.promp_sample.basis  # (T, K)
        rows = basis.new_zeros(max(16, len(steps)), basis.shape[1])  # (>= 16, K)
        rows[: len(steps)] = basis[list(steps)]
        wk = w.to(basis.dtype).unflatten(
            -1, (self.promp_sample.num_dof, self.promp_sample.num_basis)
        )  # (..., D, K)
        with one_thread():  # as ProMP.trajectory: the same bits at any thread count
            return torch.einsum("tk,...dk->...td", rows, wk)[
                ..., : len(steps), :
            ]  # (..., len(steps), D)

    def here(self, x: Tensor) -> Tensor:
        """``x`` in the evaluation dtype, on the ProMP's device."""
        return x.to(dtype=self.eval_dtype, device=self.device)

    def score(self, mu: Tensor, env: Tensor) -> Tensor:
        """Summed task costs of the mean trajectories: ``(P, N), (P, E) -> (P,)``."""
        return self.task.costs(self.promp.trajectory(self.here(mu)), self.here(env)).sum(-1)

    def predict(self, env_map, env: Tensor, need_var: bool = True) -> tuple[Tensor, Tensor | None]:
        """Eq. 7, 8 at ``env (b, E)``: ``(b, N)`` mean and variance (``None`` unless ``need_var``);
        with a labeller, the prediction of the label with the lowest :meth:`score`."""
        if self.labeler is not None:
            best = env_map.predict_best(env, self.score, need_var=need_var)
            return best.mean, best.var
        if need_var:
            return env_map.predict(env)
        return env_map.predict_mean(env), None

    def eval_success(self, env_map, eval_envs: Tensor | None) -> float | None:
        """Success rate of the map's mean trajectories on ``eval_envs (Q, E)`` (``None``: none)."""
        if eval_envs is None:
            return None
        mu_q = self.here(self.predict(env_map, eval_envs, need_var=False)[0])  # (Q, N)
        return round(
            float(self.task.success(self.promp.trajectory(mu_q), eval_envs).double().mean()), 6
        )


@dataclass(frozen=True)
class Problems:
    """The optimisation problems of one step: ``P = k b`` (``k`` labels, label-major, for
    ``each_label``; else ``k = 1``). ``env`` on the CPU in the data set's dtype; the rest in the
    evaluation dtype and device."""

    env: Tensor  # (P, E)
    env_e: Tensor  # (P, E)
    mu: Tensor  # (P, N)
    var: Tensor  # (P, N)
    mean_traj: Tensor  # (P, T, D)
    initial_success: (
        Tensor  # (b,) the start's mean solves the environment (k > 1: the lowest-cost label's)
    )
    k: int


@dataclass(frozen=True)
class Solutions:
    """The optimised solutions of one step (CPU, the data set's dtype) and which are accepted."""

    mean: Tensor  # (P, N)
    var: Tensor  # (P, N) floored by var_floor: the GP noise of a new entry
    label: Tensor  # (P,) long
    converged: Tensor  # (P,) bool
    success: Tensor  # (P,) bool
    cost: Tensor  # (P,)
    accept: Tensor  # (P,) bool


def choose(pool: Tensor, tried: list[int], known: Tensor, batch_size: int, choice: str) -> Tensor:
    """Pool indices ``(b,)`` of the next ``b <= batch_size`` untried environments of ``pool
    (num_envs, E)``: in draw order (``"random"``) or closest to any ``known (M, E)`` environment
    first (``"nearest"``; stable, ties by draw order)."""
    untried = torch.ones(pool.shape[0], dtype=torch.bool)
    untried[tried] = False
    cand = torch.nonzero(untried).flatten()  # (C,)
    b = min(batch_size, cand.numel())
    if choice == "nearest":
        d2 = torch.cdist(pool[cand], known.to(pool.dtype)).amin(1)  # (C,)
        return cand[torch.sort(d2, stable=True).indices[:b]]
    return cand[:b]


def infer(
    ev: Evaluator,
    env_map,
    env: Tensor,
    *,
    each_label: bool,
    min_var: float,
    labels: Tensor | None = None,
) -> Problems:
    """The problems at ``env (b, E)``: one per environment, started from the GP map's prediction
    (Eq. 7, 8), or with ``each_label`` one per (known label, environment), label-major (the
    labels ``labels (K,)``, default the map's); the variance floored by ``min_var``."""
    b = env.shape[0]
    if each_label:
        labs = torch.unique(env_map.labels).cpu() if labels is None else labels.cpu()  # (K,)
        k = labs.numel()
        env = env.repeat(k, 1)  # (P, E), P = K b
        mu, var = env_map.predict(env, labels=labs.repeat_interleave(b).to(env_map.labels.device))
    else:
        k = 1
        mu, var = ev.predict(env_map, env)  # (b, N), (b, N)
    mu = ev.here(mu)  # (P, N)
    var = ev.here(var).clamp_min(min_var)  # (P, N)
    env_e = ev.here(env)  # (P, E)
    mean_traj = ev.promp.trajectory(mu)  # (P, T, D)
    initial_success = ev.task.success(mean_traj, env_e)  # (P,)
    if k > 1:  # per environment: the class the label-aware inference would start from
        initial_success = per_env(initial_success, ev.task.costs(mean_traj, env_e).sum(-1), k)
    return Problems(env, env_e, mu, var, mean_traj, initial_success, k)


def sample_costs(ev: Evaluator, opt, w: Tensor, env_e: Tensor) -> Tensor:
    """Costs ``(b, S, O)`` of the asked samples ``w (b, S, N)``: only the active problems' are
    evaluated (the others' are never read), and only the objective the optimiser asked for when
    it reads one alone and the task can compute it alone (``objective_cost``), on the time steps
    it reads (``objective_steps``, optional). Problems are evaluated :func:`cost_chunks` at a time,
    so the trajectories and the task's temporaries stay in the CPU's cache."""
    active = opt.active  # (b,)
    if not bool(active.any()):
        return w.new_zeros(*w.shape[:2], opt.num_objectives or 1)  # (b, S, O)
    o = getattr(opt, "asked_objective", None)
    one_cost = (
        None if o is None else getattr(ev.task, "objective_cost", None)
    )  # optional: one objective alone, (...)
    steps = None
    if one_cost is not None and callable(getattr(ev.task, "objective_steps", None)):
        steps = ev.task.objective_steps(o)
    every = bool(active.all())  # no gather and no scatter
    w_a, env_a = (
        (w, env_e[:, None]) if every else (w[active], env_e[active][:, None])
    )  # (a, S, N), (a, 1, E)
    chunk = cost_chunks(
        w_a.shape[0],
        w_a.shape[1],
        ev.promp_sample.num_steps if steps is None else len(steps),
        ev.promp_sample.num_dof,
        w_a.shape[2],
    )
    parts = []
    for i in range(0, w_a.shape[0], chunk):
        traj = ev.sample_trajectory(w_a[i : i + chunk], steps)  # (c, S, T, D)
        env = env_a[i : i + chunk]  # (c, 1, E)
        parts.append(one_cost(traj, env, o) if one_cost is not None else ev.task.costs(traj, env))
    c = (parts[0] if len(parts) == 1 else torch.cat(parts)).to(w.dtype)  # (a, S) or (a, S, O)
    if one_cost is None and every:
        return c
    costs = c.new_zeros(
        *w.shape[:2], opt.num_objectives if one_cost is not None else c.shape[-1]
    )  # (b, S, O)
    if one_cost is None:
        costs[active] = c
    elif every:
        costs[..., o] = c
    else:
        costs[active, :, o] = c
    return costs


CHUNK_FLOATS = (
    1 << 19
)  # trajectory numbers per cost call (2 MB in float32): the fastest of 2^17 to 2^21


def cost_chunks(problems: int, samples: int, steps: int, dof: int, weights: int = 0) -> int:
    """Problems per cost call: about :data:`CHUNK_FLOATS` trajectory numbers, and a multiple of
    ``32 / gcd(S T, 32)`` problems (and of ``32 / gcd(S N, 32)`` for ``N`` weights), so that every
    call but the last fills torch's vectorised loops (32 floats) exactly and starts its tensors at
    the 64-byte alignment they have in one call on all problems: the numbers that go through a
    scalar tail (whose transcendental functions, ``hypot``, can round differently in the last
    bit) and a BLAS kernel's alignment-dependent rounding are then those of one call, and so are
    the costs."""
    unit = math.lcm(*(32 // math.gcd(samples * n, 32) for n in (steps, weights) if n))
    return min(problems, max(unit, CHUNK_FLOATS // max(samples * steps * dof, 1) // unit * unit))


def optimise(
    ev: Evaluator, problems: Problems, opt, solved: Callable[[Tensor, Tensor], Tensor] | None
):
    """Run the batched optimiser ``opt`` (started at ``problems.mu``, ``problems.var``) to its
    stop: ask, evaluate, tell. ``solved`` marks a problem converged when its mean solves it,
    before the first and after every iteration. Returns ``opt.result()``."""
    env_e = problems.env_e  # (P, E)
    if solved is not None:
        opt.mark_converged(solved(problems.mean_traj, env_e))
    while not opt.stop():
        it = opt.iteration
        w = opt.ask()  # (P, S, N)
        opt.tell(sample_costs(ev, opt, w, env_e))
        if solved is not None and opt.iteration != it and bool(opt.active.any()):
            act = opt.active
            done = torch.zeros_like(act)
            done[act] = solved(ev.promp.trajectory(opt.mean[act]), env_e[act])
            opt.mark_converged(done)
    return opt.result()


def accept(ev: Evaluator, problems: Problems, res, settings: LoopSettings) -> Solutions:
    """The solutions of ``res`` checked on all ``T`` steps, labelled, and the accepted ones
    (``settings.add_only``; with ``k > 1`` labels at most one per environment and final label,
    the cheapest)."""
    final_traj = ev.promp.trajectory(res.mean)  # (P, T, D)
    success = ev.task.success(final_traj, problems.env_e).cpu()  # (P,)
    converged = res.converged.cpu()  # (P,)
    cost = (
        ev.task.costs(final_traj, problems.env_e).sum(-1).to(device="cpu", dtype=ev.dtype)
    )  # (P,)
    ok = {"converged": converged, "success": success, "all": torch.ones_like(success)}[
        settings.add_only
    ]
    label = (
        torch.zeros(ok.shape[0], dtype=torch.long)
        if ev.labeler is None
        else torch.as_tensor(ev.labeler(final_traj, problems.env_e)).to(
            device="cpu", dtype=torch.long
        )
    )
    if (
        problems.k > 1
    ):  # two problems of one environment that ended in the same class: keep the cheaper
        ok = one_per_class(ok, label, cost, problems.k)
    return Solutions(
        mean=res.mean.to(device="cpu", dtype=ev.dtype),
        var=res.var.to(device="cpu", dtype=ev.dtype).clamp_min(settings.var_floor),
        label=label,
        converged=converged,
        success=success,
        cost=cost,
        accept=ok,
    )


def add(dataset: TrajectoryDataset, env_map, env: Tensor, sol: Solutions) -> None:
    """Append the accepted solutions at ``env (P, E)`` to the data set and to the map."""
    a = sol.accept
    if bool(a.any()):
        dataset.append(
            env[a],
            sol.mean[a],
            sol.var[a],
            label=sol.label[a],
            origin="learned",
            converged=sol.converged[a],
            cost=sol.cost[a],
        )
        env_map.add(env[a], sol.mean[a], sol.var[a], sol.label[a])


def step_row(
    step: int, envs_done: int, dataset_size: int, problems: Problems, res, sol: Solutions
) -> dict:
    """The metrics row of a step (``eval_success``, ``success_rate`` and ``seconds`` are the
    caller's). ``initial_success`` and ``success`` count environments: with ``k > 1`` labels,
    each environment's lowest-cost problem; ``rollouts`` the optimiser's samples evaluated."""
    k = problems.k
    success = (
        sol.success if k == 1 else per_env(sol.success, sol.cost, k)
    )  # (b,) the lowest-cost class's
    iters = iterations_per_problem(res, problems.mu)
    return {
        "step": step,
        "envs_done": envs_done,
        "dataset_size": dataset_size,
        "batch": problems.env.shape[0] // k,
        "added": int(sol.accept.sum()),
        "initial_success": int(problems.initial_success.sum()),
        "success": int(success.sum()),
        "converged": int(sol.converged.sum()),
        "iterations_mean": round(float(iters.double().mean()), 3),
        "iterations_max": int(iters.max()),
        "rollouts": None if res.rollouts is None else int(res.rollouts.sum()),
    }


def one_per_class(accept: Tensor, label: Tensor, cost: Tensor, k: int) -> Tensor:
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


def per_env(flag: Tensor, cost: Tensor, k: int) -> Tensor:
    """``flag (K b,)`` of label-major problems -> ``(b,)``: the flag of each environment's
    lowest-cost problem (``cost (K b,)``)."""
    b = flag.shape[0] // k
    best = cost.reshape(k, b).argmin(0).to(flag.device)  # (b,)
    return flag.reshape(k, b)[best, torch.arange(b, device=flag.device)]


def iterations_per_problem(res, mean0: Tensor) -> Tensor:
    """Iterations each problem ran before it stopped moving: ``(B,)`` long. A converged problem's
    mean stays fixed, so this is the last iteration whose mean differs from the one before
    (``mean0 (B, N)``: the start)."""
    hist = res.history.get("mean")
    if hist is None or hist.shape[0] == 0:
        return torch.zeros(mean0.shape[0], dtype=torch.long)
    prev = torch.cat([mean0[None].to(hist), hist[:-1]])  # (I, B, N)
    moved = (hist != prev).any(-1).cpu()  # (I, B)
    it = torch.arange(1, hist.shape[0] + 1)[:, None].expand_as(moved)  # (I, B)
    return torch.where(moved, it, torch.zeros_like(it)).amax(0)  # (B,)
