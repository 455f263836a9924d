"""The refill loop (``refill=True``): the paper's sequential algorithm run by ``B`` workers.

``B`` environments are in flight at once (``K`` problems each: one per known label with
``each_label``, else one), in the rows of one long-lived batched optimiser. After every iteration
each environment whose problems have all stopped (converged, solved, or out of their
``max_iter`` iterations) is finished at once: its solutions are checked, accepted and added to
the data set and the map, and its slot gets the next untried environment, inferred from the map
as it is now (:meth:`~protorch.optim.base.BaseOptimizer.restart`). No slot waits for the slowest
problem of a step, and every environment starts from a map that already holds every solution
finished before it. With ``refill_group`` ``g > 1`` finished environments wait (their rows idle)
until ``g`` of them are done, and are added and refilled together: a map whose add costs
``O(M^2)`` (the exact GP without ``nearest_k``) is then updated ``g`` times less often.

Steps here are bookkeeping: a metrics row (and ``eval_success``, the checkpoint, ``on_step``) is
written each time at least ``B`` more environments have finished, and after the last. ``tried``
lists the finished environments in the order they finished; each row's ``adds`` the sizes of the
map's adds, so a resumed run replays them exactly. Each checkpoint also saves what is in flight
(:mod:`.inflight`: the optimiser's state and random generator, the slots, the environments
started, the slots waiting for their next environment), and a resumed run puts it back and goes
on from there: a killed run resumes bit for bit as the uninterrupted run goes on. (A checkpoint
without that state, an older protorch's, restarts the problems in flight from the map, with a
warning: every environment is still tried once, but the numbers differ.)
"""

from __future__ import annotations

import inspect
import warnings
from types import SimpleNamespace

import torch
from torch import Tensor

from ..data.files import CheckpointError
from ..optim.base import BaseOptimizer
from ..threads import core_budget
from .inflight import load_optimizer_state, optimizer_state
from .phases import Problems, accept, add, choose, infer, per_env, sample_costs

__all__ = ["problem_budget", "refill_loop"]


def problem_budget(optimizer: type, optimizer_kwargs: dict) -> int:
    """The iterations one problem may run: ``optimizer_kwargs["max_iter"]`` or the
    class's default."""
    if "max_iter" in optimizer_kwargs:
        return int(optimizer_kwargs["max_iter"])
    for cls in (optimizer, BaseOptimizer):
        p = inspect.signature(cls.__init__).parameters.get("max_iter")
        if p is not None and p.default is not inspect.Parameter.empty:
            return int(p.default)
    raise ValueError(f"{optimizer.__name__} has no max_iter")


class Slots:
    """``B`` slots of ``K`` optimiser rows each (row ``l B + j``: label ``l`` of slot ``j``) and
    what the loop knows of the environment in each: its pool index (``-1``: free), the
    environment (CPU, data set dtype, and in the evaluation dtype per row), the start's success
    and, per row, the age at which it first stopped (``-1``: still moving) and whether it had
    converged then (a row out of iterations is frozen, marked converged in the optimiser, while it
    waits for its environment's other rows or its group)."""

    def __init__(self, b: int, k: int, env_dim: int, ev) -> None:
        self.b, self.k = b, k
        self.pick = torch.full((b,), -1, dtype=torch.long)  # (B,)
        self.env = torch.zeros(b, env_dim, dtype=ev.dtype)  # (B, E)
        self.env_e = torch.zeros(k * b, env_dim, dtype=ev.eval_dtype, device=ev.device)  # (K B, E)
        self.initial_success = torch.zeros(b, dtype=torch.bool)  # (B,)
        self.stopped_at = torch.full((k * b,), -1, dtype=torch.long)  # (K B,)
        self.converged = torch.zeros(
            k * b, dtype=torch.bool
        )  # (K B,) whether it converged when it stopped
        self.pending: Tensor | None = None  # (s,) finished slots not yet given their next one

    _SAVED = ("pick", "env", "env_e", "initial_success", "stopped_at", "converged")

    def state(self) -> dict[str, Tensor]:
        """The slots' tensors, for the in-flight checkpoint (``slots.<name>``)."""
        return {f"slots.{k}": getattr(self, k) for k in self._SAVED}

    def load(self, tensors: dict[str, Tensor]) -> None:
        """Put :meth:`state`'s tensors back (the same ``B``, ``K`` and environment size)."""
        for k in self._SAVED:
            mine, saved = getattr(self, k), tensors[f"slots.{k}"]
            if saved.shape != mine.shape or saved.dtype != mine.dtype:
                raise CheckpointError(
                    f"the checkpoint's slots have {k} {tuple(saved.shape)} {saved.dtype}, this "
                    f"run's {tuple(mine.shape)} {mine.dtype}"
                )
            mine.copy_(saved)

    def rows(self, slots: Tensor) -> Tensor:
        """Optimiser rows of ``slots (s,)``, label-major: ``(K s,)``."""
        return (torch.arange(self.k)[:, None] * self.b + slots[None]).reshape(-1)

    @property
    def busy(self) -> Tensor:
        return self.pick >= 0  # (B,)

    def fill(self, slots: Tensor, picks: Tensor, problems: Problems) -> None:
        rows = self.rows(slots)
        self.pick[slots] = picks
        self.env[slots] = problems.env[: slots.numel()].to(self.env)
        self.env_e[rows.to(self.env_e.device)] = problems.env_e
        self.initial_success[slots] = problems.initial_success.cpu()
        self.stopped_at[rows] = -1


def refill_loop(
    *,
    ev,
    gp,
    data,
    pool: Tensor,
    state,
    settings,
    optimizer: type,
    optimizer_kwargs: dict,
    solved,
    labels: Tensor | None,
    finish_step,
) -> None:
    """Run the refill loop (module docstring) until every untried environment of ``pool`` is
    finished; ``state`` (:class:`~protorch.loop.state.RunState`) holds the finished ones, ``data``
    and ``gp`` grow. ``finish_step(row)`` completes and records a metrics row (``eval_success``,
    ``success_rate``, seconds, checkpoint, progress, ``on_step``)."""
    budget = problem_budget(optimizer, optimizer_kwargs)
    k = 1 if labels is None else int(labels.numel())
    todo = settings.num_envs - len(state.tried)
    restored, state.restored = state.restored, None
    if todo <= 0:
        return
    if restored is not None:  # the slots as the checkpoint left them
        b = int(restored[1]["slots"])
        if int(restored[1]["labels"]) != k:
            raise CheckpointError(
                f"the checkpoint's loop has {restored[1]['labels']} label(s) per environment in "
                f"flight, this run {k}"
            )
        slots = Slots(b, k, pool.shape[1], ev)
        slots.load(restored[0])
        started: list[int] = [int(i) for i in restored[1]["started"]]  # finished or in flight
    else:
        b = min(settings.batch_size, todo)
        slots = Slots(b, k, pool.shape[1], ev)
        started = list(state.tried)
        if state.resumed_from is not None:
            warnings.warn(
                f"{state.checkpoint_file} holds no state of the environments in flight (written "
                "by an older protorch): they start again from the map, and the resumed run's "
                "numbers are not those of an uninterrupted run",
                stacklevel=3,
            )

    def start(free: Tensor):
        """Problems for the next untried environments in ``free (s,)`` slots (fewer if the pool
        runs dry): ``(slots filled, their problems)``."""
        picks = choose(pool, started, data.env, free.numel(), settings.choice)  # (s',)
        started.extend(picks.tolist())
        free = free[: picks.numel()]
        if picks.numel() == 0:
            return free, None
        problems = infer(
            ev,
            gp,
            pool[picks],
            each_label=settings.each_label,
            min_var=settings.min_var,
            labels=labels,
        )
        slots.fill(free, picks, problems)
        return free, problems

    kwargs = {**optimizer_kwargs, "max_iter": 2**62}  # the budget is per problem: ``budget``
    if restored is None:
        filled, first = start(torch.arange(b))
        opt = optimizer(first.mu, first.var, seed=settings.step_seed(state.step + 1), **kwargs)
        opt.history_limit = max(1, opt.convergence.window)
    else:  # the optimiser the checkpoint saved, rebuilt at its size and given its state
        shape = (k * b, data.mean.shape[1])  # (K B, N)
        blank = torch.zeros(shape, dtype=ev.eval_dtype, device=ev.device)
        opt = optimizer(blank, torch.ones_like(blank), seed=0, **kwargs)
        opt.history_limit = max(1, opt.convergence.window)
        load_optimizer_state(
            opt,
            {n.removeprefix("opt."): t for n, t in restored[0].items() if n.startswith("opt.")},
            restored[1]["optimizer"],
        )
    acc = _Accumulator()

    def in_flight() -> tuple[dict, dict] | None:
        """What a checkpoint saves of the work in flight (``None`` once every environment is
        finished): taken in ``finish_step``, where the metrics row was just taken (``acc``
        empty) and the finished slots wait for their next environment (``slots.pending``)."""
        if len(state.tried) >= settings.num_envs:
            return None
        if acc.batch:
            raise RuntimeError("the refill loop checkpoints only right after a metrics row")
        ot, om = optimizer_state(opt)
        pending = [] if slots.pending is None else slots.pending.tolist()
        meta = {"slots": b, "labels": k, "started": started, "pending": pending, "optimizer": om}
        return {**slots.state(), **{f"opt.{n}": t for n, t in ot.items()}}, meta

    if state.run_dir is not None:
        optimizer_state(opt)  # an optimiser whose state cannot be saved is refused before work
        state.inflight = in_flight
    if torch.get_num_threads() < core_budget() and callable(getattr(opt, "draw_ahead", None)):
        opt.draw_ahead()
    if restored is None:
        if solved is not None:
            opt.mark_converged(solved(first.mean_traj, slots.env_e))
    else:  # the checkpoint was taken before its finished slots got their next environments
        _refill(
            opt, slots, torch.as_tensor(restored[1]["pending"], dtype=torch.long), start, solved
        )
    while True:
        _finish_and_refill(
            ev, gp, data, opt, slots, settings, budget, solved, state, acc, start, finish_step
        )
        if not bool(slots.busy.any()):
            break
        it = opt.iteration
        while opt.iteration == it:
            w = opt.ask()  # (K B, S, N)
            opt.tell(sample_costs(ev, opt, w, slots.env_e))
        if solved is not None and bool(opt.active.any()):
            act = opt.active
            done = torch.zeros_like(act)
            done[act] = solved(ev.promp.trajectory(opt.mean[act]), slots.env_e[act])
            opt.mark_converged(done)
    state.inflight = None  # every environment finished: nothing in flight
    if acc.batch:
        finish_step(acc.row())
    opt.stop()  # cancels a draw made ahead


class _Accumulator:
    """The metrics of the environments finished since the last row."""

    def __init__(self) -> None:
        self.batch = self.added = self.initial = self.success = self.converged = self.rollouts = 0
        self.iterations: list[Tensor] = []
        self.adds: list[int] = []

    def take(self, problems: Problems, sol, iterations: Tensor, rollouts: int) -> None:
        k = problems.k
        self.batch += problems.env.shape[0] // k
        self.added += int(sol.accept.sum())
        self.initial += int(problems.initial_success.sum())
        self.success += int((sol.success if k == 1 else per_env(sol.success, sol.cost, k)).sum())
        self.converged += int(sol.converged.sum())
        self.iterations.append(iterations)
        self.rollouts += rollouts
        if int(sol.accept.sum()):
            self.adds.append(int(sol.accept.sum()))

    def row(self) -> dict:
        """The row's counts (``step``, ``envs_done`` and the rest are the caller's); resets."""
        iters = torch.cat(self.iterations).double()
        row = {
            "batch": self.batch,
            "added": self.added,
            "initial_success": self.initial,
            "success": self.success,
            "converged": self.converged,
            "iterations_mean": round(float(iters.mean()), 3),
            "iterations_max": int(iters.max()),
            "rollouts": self.rollouts,
            "adds": list(self.adds),
        }
        self.__init__()
        return row


def _finish_and_refill(
    ev,
    gp,
    data,
    opt,
    slots: Slots,
    settings,
    budget: int,
    solved,
    state,
    acc: _Accumulator,
    start,
    finish_step,
) -> None:
    """Finish every busy slot whose rows all stopped, add its accepted solutions, give it the next
    environment (or leave it free, its rows parked), until no busy slot is done."""
    while True:
        age = opt.age  # (K B,) CPU
        conv = opt.converged.cpu()  # (K B,)
        stopped = conv | (age >= budget)  # (K B,)
        first = stopped & (slots.stopped_at < 0)
        slots.stopped_at[first] = age[first]
        slots.converged[first] = conv[first]
        if bool(
            (first & ~conv).any()
        ):  # out of iterations: frozen while it waits (its flag kept above)
            opt.mark_converged((first & ~conv).to(opt.converged.device))
        done = stopped.reshape(slots.k, slots.b).all(0) & slots.busy  # (B,)
        group = min(
            settings.refill_group, int(slots.busy.sum())
        )  # the last ones finish as they come
        if int(done.sum()) < max(group, 1):
            return
        idx = done.nonzero().flatten()  # (s,)
        rows = slots.rows(idx)  # (K s,)
        rows_d = rows.to(opt.mean.device)
        problems = Problems(
            env=slots.env[idx].repeat(slots.k, 1),
            env_e=slots.env_e[rows_d],
            mu=opt.mean[rows_d],
            var=opt.var[rows_d],
            mean_traj=None,
            initial_success=slots.initial_success[idx],
            k=slots.k,
        )
        res = SimpleNamespace(
            mean=opt.mean[rows_d], var=opt.var[rows_d], converged=slots.converged[rows]
        )
        sol = accept(ev, problems, res, settings)
        add(data, gp, problems.env, sol)
        acc.take(problems, sol, slots.stopped_at[rows], int(opt.rollouts[rows].sum()))
        state.tried.extend(slots.pick[idx].tolist())
        slots.pick[idx] = -1
        if acc.batch >= settings.batch_size:
            slots.pending = idx  # a checkpoint here saves them as waiting for their next ones
            finish_step(acc.row())
        _refill(opt, slots, idx, start, solved)


def _refill(opt, slots: Slots, idx: Tensor, start, solved) -> None:
    """Give the finished slots ``idx (s,)`` the next untried environments (``start``), restarting
    their optimiser rows; the slots left without one are parked (their rows marked converged)."""
    slots.pending = None
    filled, problems = start(idx)
    if problems is not None:
        frows = slots.rows(filled)
        opt.restart(frows.to(opt.mean.device), problems.mu, problems.var)
        if solved is not None:
            opt.mark_converged(_rows_mask(opt, frows, solved(problems.mean_traj, problems.env_e)))
    parked = idx[filled.numel() :]
    if parked.numel():
        opt.mark_converged(_rows_mask(opt, slots.rows(parked), True))


def _rows_mask(opt, rows: Tensor, value) -> Tensor:
    """A ``(K B,)`` bool mask, ``value`` (a bool or ``(r,)`` bools) at ``rows`` and False
    elsewhere."""
    mask = torch.zeros_like(opt.converged)
    mask[rows.to(mask.device)] = torch.as_tensor(value, device=mask.device)
    return mask
