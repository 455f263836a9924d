"""The ask / tell / stop / result contract shared by every optimiser (after pycma).

An optimiser holds a diagonal Gaussian over ProMP weights for ``B`` independent problems at
once (buffers ``mean (B, N)``, ``var (B, N)``); evaluation stays outside::

    opt = PRO(mean, var, beta=20.0)
    while not opt.stop():
        w = opt.ask()                      # (B, S, N) weights to evaluate
        opt.tell(objective(w))             # (B, S, O) costs, >= 0, lower is better
    res = opt.result()

Each algorithm is written top to bottom as a generator (``_iteration``) that yields the weights
it wants evaluated and receives their costs, so one iteration may ask several times (PRO asks
once for its relevance samples and once per objective). ``B`` problems advance together: one
``ask`` serves all of them, which is what makes the batched self-improvement loop fast.
An optimiser built from an unbatched ``mean (N,)`` speaks unbatched shapes: ``ask`` gives
``(S, N)``, ``tell`` takes ``(S, O)`` or ``(S,)`` and ``result`` drops the batch dimension.
"""

from __future__ import annotations

from typing import Callable, Generator

import torch
from torch import Tensor, nn

from ..checks import check_int, check_number, check_positive, check_tensor
from .contract import OptimizeResult, check_costs
from .convergence import make_rule
from .draws import NormalDraws

__all__ = ["BaseOptimizer", "OptimizeResult"]


class BaseOptimizer(nn.Module):
    """Common state and contract; subclasses implement :meth:`_iteration`.

    Args:
        mean: ``(N,)`` or ``(B, N)`` initial mean.
        var: initial diagonal variance, same shape as ``mean`` (or broadcastable), >= 0.
        beta: reward temperature ``R = exp(-beta * cost)``: a float or ``(B,)``.
        num_samples: ``S`` rollouts per update.
        max_iter: hard limit on iterations.
        tol, window: a problem has converged once every objective's mean sample cost stayed
            within ``tol`` (max - min) over the last ``window`` iterations (``convergence="mean"``).
            ``tol=0`` disables it. Converged problems stop moving.
        convergence: ``"mean"`` (above), ``"authors"`` (every sample's cost within ``tol``, the
            authors' ``rwpo.py``) or a rule object (:mod:`protorch.optim.convergence`).
        num_objectives: ``O``; inferred from the first ``tell`` when ``None``.
        seed: seed of the optimiser's own ``torch.Generator`` (reproducible sampling).
        dtype: dtype of the distribution (float64 default; float32 is fine for sampling).
    """

    mean: Tensor  # (B, N) registered buffers, typed for the type checker
    var: Tensor  # (B, N)
    beta: Tensor  # (B,)
    converged: Tensor  # (B,) bool
    can_draw_ahead = True  # every random number comes through _randn (see draw_ahead)

    @property
    def can_restart(self) -> bool:
        """Whether :meth:`restart` may give a problem's row a new problem between iterations (the
        loop's refill); an optimiser whose state reads the global iteration or pools iterations
        sets this to False."""
        return True

    def __init__(
        self,
        mean: Tensor,
        var: Tensor,
        *,
        beta: float | Tensor,
        num_samples: int = 100,
        max_iter: int = 200,
        tol: float = 1e-3,
        window: int = 5,
        convergence="mean",
        num_objectives: int | None = None,
        seed: int | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        mean = check_tensor(mean, "mean")
        if mean.ndim not in (1, 2):
            raise ValueError(f"mean must be (N,) or (B, N), got shape {tuple(mean.shape)}")
        self.batched = mean.ndim == 2
        dtype = dtype or (mean.dtype if mean.is_floating_point() else torch.float64)
        mean = mean.to(dtype)
        mean2 = mean if self.batched else mean[None]  # (B, N)
        var = check_tensor(torch.as_tensor(var, dtype=dtype, device=mean.device), "var")
        if bool((var < 0).any()):
            raise ValueError("var must be >= 0")
        try:
            var2 = torch.broadcast_to(
                var if self.batched or var.ndim < 1 else var[None], mean2.shape
            )
        except RuntimeError:
            raise ValueError(
                f"var of shape {tuple(var.shape)} does not match mean {tuple(mean.shape)}"
            ) from None
        beta_t = torch.as_tensor(beta, dtype=dtype, device=mean.device)
        check_positive(beta_t, "beta")
        if beta_t.ndim > 1 or (beta_t.ndim == 1 and beta_t.shape[0] not in (1, mean2.shape[0])):
            raise ValueError(
                f"beta must be a float or ({mean2.shape[0]},), got shape {tuple(beta_t.shape)}"
            )
        for name, v, lo in (("num_samples", num_samples, 2), ("max_iter", max_iter, 1)):
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v < lo:
                raise ValueError(f"{name} must be >= {lo}, got {v}")
        num_samples, max_iter = (
            check_int(num_samples, "num_samples", 2),
            check_int(max_iter, "max_iter", 1),
        )
        if (
            isinstance(tol, (int, float))
            and tol < 0
            or isinstance(window, (int, float))
            and window < 1
        ):
            raise ValueError(f"need tol >= 0 and window >= 1, got tol={tol}, window={window}")
        tol, window = check_number(tol, "tol", allow_zero=True), check_int(window, "window", 1)
        if num_objectives is not None:
            num_objectives = check_int(num_objectives, "num_objectives", 1)
        self.register_buffer("mean", mean2.clone())  # (B, N)
        self.register_buffer("var", var2.clone())  # (B, N)
        self.register_buffer("beta", beta_t.expand(mean2.shape[0]).clone())  # (B,)
        self.register_buffer(
            "converged", torch.zeros(mean2.shape[0], dtype=torch.bool, device=mean.device)
        )
        self.num_samples = int(num_samples)
        self.max_iter = int(max_iter)
        self.tol = float(tol)
        self.window = int(window)
        self.convergence = make_rule(convergence, tol=self.tol, window=self.window)
        self.num_objectives = None if num_objectives is None else int(num_objectives)
        self.generator = torch.Generator(device=mean.device)
        if seed is not None:
            self.generator.manual_seed(int(seed))
        else:
            self.generator.seed()
        self.draws = NormalDraws(
            self.generator
        )  # every sample's noise comes from here (see draw_ahead)
        self.iteration = 0
        self.history: dict[str, list[Tensor]] = {
            "cost": [],
            "cost_min": [],
            "cost_max": [],
            "mean": [],
            "var": [],
        }
        self.relevance_seconds: list[float] = []
        self.rollouts = torch.zeros(
            mean2.shape[0], dtype=torch.long
        )  # (B,) samples told while active
        self.age = torch.zeros(
            mean2.shape[0], dtype=torch.long
        )  # (B,) iterations since each row's problem began
        self.history_limit: int | None = (
            None  # keep only this many iterations of history (None: all)
        )
        self._gen: Generator[Tensor, Tensor, None] | None = None
        self._next: Tensor | None = None
        # the objective whose costs the pending ask's update reads (None: it reads all of them);
        # a caller may fill the other columns with any finite value (e.g. skip computing them)
        self.asked_objective: int | None = None
        self._asked: Tensor | None = None
        self._iter_cost: Tensor | None = None
        self._start: dict = {}  # the state at the start of the current iteration

    # -------------------------------------------------------------- sizes
    @property
    def batch_size(self) -> int:
        return self.mean.shape[0]

    @property
    def num_weights(self) -> int:
        return self.mean.shape[1]

    # ------------------------------------------------------------ helpers
    def _randn(self, *shape: int) -> Tensor:
        return self.draws.draw(shape, self.mean.dtype, self.mean.device)

    def draw_ahead(self) -> bool:
        """Draw each next ask's noise in a background thread while the caller evaluates (the same
        numbers in the same order, :mod:`~protorch.optim.draws`; a CPU generator,
        ``can_draw_ahead``).
        Returns whether it is on; the generator is then busy between asks (use it only here)."""
        if self.can_draw_ahead:
            self.draws.start_ahead()
        return self.draws.ahead

    def _sample(self, var: Tensor, num: int) -> Tensor:
        """``num`` draws from ``N(mean, diag(var))`` per problem: ``var (B, N)`` -> ``(B, num,
        N)``."""
        eps = self._randn(self.batch_size, num, self.num_weights)  # (B, S, N)
        return eps.mul_(var.clamp_min(0).sqrt()[:, None, :]).add_(
            self.mean[:, None, :]
        )  # mean + eps std

    def _active_rows(self) -> Tensor | None:
        """Indices ``(r,)`` of the problems to update (``None``: all): every block of ``64 /
        itemsize``
        problems holding a moving one. BLAS rounds by the 64-byte alignment of a problem's matrices,
        which whole blocks keep: the numbers are those of an update over all ``B``."""
        moving = ~self.converged  # (B,)
        if bool(moving.all()):
            return None
        block = max(1, 64 // self.mean.element_size())
        kept = torch.zeros(
            (self.batch_size + block - 1) // block, dtype=torch.bool, device=moving.device
        )
        kept.index_fill_(0, moving.nonzero().flatten() // block, True)  # (blocks,)
        return kept.repeat_interleave(block)[: self.batch_size].nonzero().flatten()

    def _apply_rows(self, rows: Tensor | None, new_mean: Tensor, new_var: Tensor) -> None:
        """Commit an update computed for ``rows`` (``None``: all, :meth:`_commit`) to its moving
        ones."""
        if rows is None:
            self._commit(new_mean, new_var)
            return
        moving = ~self.converged[rows]  # (r,)
        self.mean[rows[moving]] = new_mean[moving]
        self.var[rows[moving]] = new_var[moving].clamp_min(0)

    @property
    def _objectives(self) -> int:
        """``O``: given, or set by the first ``tell``."""
        if self.num_objectives is None:
            raise RuntimeError("the number of objectives is not known before the first tell()")
        return self.num_objectives

    def _record_cost(self, objective: int | slice, costs: Tensor) -> None:
        """Note the mean, min and max cost this iteration's update saw for ``objective``:
        ``costs (B, S[, O])``."""
        if self._iter_cost is None:
            self._iter_cost = torch.full(
                (3, self.batch_size, self._objectives),
                float("nan"),
                dtype=costs.dtype,
                device=costs.device,
            )  # (3, B, O): mean, min, max over the samples
        self._iter_cost[0][:, objective] = costs.mean(1)
        self._iter_cost[1][:, objective] = costs.amin(1)
        self._iter_cost[2][:, objective] = costs.amax(1)

    def _set_objective_weights(self, objective_weights) -> None:
        """``objective_weights (O,)`` for optimisers that score one total cost (``None``: all
        ones)."""
        if objective_weights is None:
            self.objective_weights = None
            return
        c = check_tensor(
            torch.as_tensor(objective_weights, dtype=self.mean.dtype, device=self.mean.device),
            "objective_weights",
            ndim=1,
        )
        if self.num_objectives is not None and c.shape[0] != self.num_objectives:
            raise ValueError(
                f"objective_weights must be ({self.num_objectives},), got {tuple(c.shape)}"
            )
        self.objective_weights = c

    def _total_cost(self, costs: Tensor) -> Tensor:
        """``costs (B, S, O)`` -> ``(B, S)``: the objectives combined with ``objective_weights``."""
        c = self.objective_weights  # its shape was checked against the costs by tell()
        return costs.sum(-1) if c is None else costs @ c

    def _commit(self, new_mean: Tensor, new_var: Tensor) -> None:
        """Commit an update to the problems that have not converged."""
        active = ~self.converged[:, None]  # (B, 1)
        self.mean.copy_(torch.where(active, new_mean, self.mean))
        self.var.copy_(torch.where(active, new_var.clamp_min(0), self.var))

    # ------------------------------------------------------------ contract
    def _iteration(self) -> Generator[Tensor, Tensor, None]:  # pragma: no cover - abstract
        raise NotImplementedError

    def ask(self) -> Tensor:
        """Weights to evaluate next: ``(B, S, N)`` (``(S, N)`` unbatched)."""
        if self._asked is not None:
            raise RuntimeError("ask() called twice without tell() in between")
        if self.stop():
            raise RuntimeError(f"the optimiser has stopped ({self.stop_reason()}); read result()")
        if self._next is None:
            self._start = self._snapshot()
            self.draws.new_iteration()
            self._gen = self._iteration()
            self._next = next(self._gen)
        self._asked = self._next
        return self._asked if self.batched else self._asked[0]

    def tell(self, costs: Tensor) -> None:
        """Costs of the last asked weights: ``(B, S, O)`` (unbatched: ``(S, O)`` or ``(S,)``)."""
        if self._asked is None or self._gen is None:
            raise RuntimeError("tell() called without a pending ask()")
        costs = self._checked_costs(costs, self._asked)
        self._asked = None
        self.rollouts += self.active.cpu().long() * costs.shape[1]
        try:
            self._next = self._gen.send(costs)
        except StopIteration:
            self._next = None
            self._end_iteration()
        except BaseException:  # an update failed half-way: back to the start of the iteration
            self._restore(self._start)
            raise

    def _checked_costs(self, costs, asked: Tensor) -> Tensor:
        """``costs`` of the ``asked (B, S, N)`` weights as ``(B, S, O)`` in the distribution's
        dtype (:func:`~.contract.check_costs`); nothing changes before every check passed."""
        cast = check_costs(
            costs,
            batched=self.batched,
            expect=(asked.shape[0], asked.shape[1]),
            dtype=self.mean.dtype,
            num_objectives=self.num_objectives,
            objective_weights=getattr(self, "objective_weights", None),
        )
        if self.num_objectives is None:
            self.num_objectives = cast.shape[-1]
        return cast

    def _snapshot(self) -> dict:
        """What an iteration may change, to undo an iteration that failed inside ``tell``."""
        return {
            "mean": self.mean.clone(),
            "var": self.var.clone(),
            "converged": self.converged.clone(),
            "rng": self.draws.get_state(),
            "num_objectives": self.num_objectives,
            "history": {k: len(v) for k, v in self.history.items()},
            "relevance_seconds": len(self.relevance_seconds),
            "relevance": getattr(self, "relevance", None),
            "rollouts": self.rollouts.clone(),
        }

    def _restore(self, snap: dict) -> None:
        self.mean.copy_(snap["mean"])
        self.var.copy_(snap["var"])
        self.converged.copy_(snap["converged"])
        self.draws.set_state(snap["rng"])
        self.num_objectives = snap["num_objectives"]
        for k, n in snap["history"].items():
            del self.history[k][n:]
        del self.relevance_seconds[snap["relevance_seconds"] :]
        self.rollouts.copy_(snap["rollouts"])
        if hasattr(self, "relevance"):
            self.relevance = snap["relevance"]
        self._gen, self._next, self._asked, self._iter_cost = None, None, None, None
        self.asked_objective = None

    def _end_iteration(self) -> None:
        self.iteration += 1
        cost = self._iter_cost
        self._iter_cost = None
        self.history["mean"].append(self.mean.clone())
        self.history["var"].append(self.var.clone())
        if cost is not None:
            for key, c in zip(("cost", "cost_min", "cost_max"), cost):
                self.history[key].append(c)  # (B, O)
        self.age += 1
        if len(self.history["cost"]) >= self.convergence.window:
            # a restarted row's window must hold its own problem's iterations only (a no-op
            # without restarts: every row's age is then the iteration count)
            self.converged |= self.convergence(self.history) & (
                self.age >= self.convergence.window
            ).to(self.converged.device)
        if self.history_limit is not None:
            for v in self.history.values():
                del v[: -self.history_limit]

    def restart(self, rows: Tensor, mean: Tensor, var: Tensor) -> None:
        """Give rows ``rows (r,)`` new problems started at ``mean, var (r, N)``, between two
        iterations: their distribution, convergence flag, age and rollout count start afresh; the
        other rows are untouched (the loop's refill, :func:`protorch.loop.self_improve`). Needs
        ``history_limit`` (a long-lived optimiser keeps only the iterations its rule reads)."""
        if not self.can_restart:
            raise ValueError(
                f"{type(self).__name__} cannot restart single problems (its state is not per "
                "problem)"
            )
        if self._asked is not None or self._next is not None:
            raise RuntimeError("restart() is only possible between iterations")
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.mean.device).reshape(-1)
        mean = torch.as_tensor(mean, dtype=self.mean.dtype, device=self.mean.device)
        var = torch.as_tensor(var, dtype=self.mean.dtype, device=self.mean.device)
        if tuple(mean.shape) != (rows.numel(), self.num_weights) or mean.shape != var.shape:
            raise ValueError(
                f"restart needs mean and var ({rows.numel()}, {self.num_weights}), got "
                f"{tuple(mean.shape)} and {tuple(var.shape)}"
            )
        if bool((var < 0).any()):
            raise ValueError("var must be >= 0")
        self.mean[rows] = mean
        self.var[rows] = var
        self.converged[rows] = False
        cpu = rows.cpu()
        self.age[cpu] = 0
        self.rollouts[cpu] = 0

    def mark_converged(self, mask) -> None:
        """Declare problems finished from outside, e.g. once their mean already solves the task
        (the self-improvement loop's ``solved`` check): they stop moving, count as converged and
        :meth:`stop` does not wait for them. ``mask`` is ``(B,)`` bool (unbatched: a bool)."""
        m = torch.as_tensor(mask, device=self.converged.device)
        if m.dtype != torch.bool:
            raise ValueError(f"mask must be bool, got {m.dtype}")
        if not self.batched and m.numel() == 1:
            m = m.reshape(1)
        if tuple(m.shape) != (self.batch_size,):
            raise ValueError(f"mask must be ({self.batch_size},) bool, got shape {tuple(m.shape)}")
        self.converged |= m

    @property
    def active(self) -> Tensor:
        """``(B,)`` bool: problems still moving (not converged). Their costs are the only ones an
        update reads, so a caller may skip evaluating the others (any finite cost will do)."""
        return ~self.converged

    def stop_reason(self) -> str | None:
        if bool(self.converged.all()):
            return "converged"
        if self.iteration >= self.max_iter:
            return "max_iter"
        return None

    def stop(self) -> bool:
        """True once every problem converged or ``max_iter`` iterations ran."""
        done = self._asked is None and self._next is None and self.stop_reason() is not None
        if done:  # a draw made ahead for an ask that will not come
            self.draws.cancel()
        return done

    def result(self) -> OptimizeResult:
        def unb(x: Tensor, axis: int = 0) -> Tensor:
            return x if self.batched else x.squeeze(axis)

        hist = {k: unb(torch.stack(v), 1) for k, v in self.history.items() if v}
        return OptimizeResult(
            mean=unb(self.mean.clone()),
            var=unb(self.var.clone()),
            converged=unb(self.converged.clone()),
            iterations=self.iteration,
            history=hist,
            relevance_seconds=list(self.relevance_seconds),
            rollouts=unb(self.rollouts.clone()),
        )

    def minimize(
        self,
        objective: Callable[[Tensor], Tensor],
        *,
        callback: Callable[["BaseOptimizer"], None] | None = None,
        progress: bool = False,
    ) -> OptimizeResult:
        """Run ask/tell until :meth:`stop`; ``objective`` maps ``(B, S, N)`` to ``(B, S, O)``
        (unbatched ``(S, N)`` to ``(S, O)``). ``callback(self)`` runs after each iteration."""
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=self.max_iter, desc=type(self).__name__, leave=False)
        while not self.stop():
            it = self.iteration
            self.tell(objective(self.ask()))
            if self.iteration != it:
                if callback is not None:
                    callback(self)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(converged=f"{int(self.converged.sum())}/{self.batch_size}")
        if bar is not None:
            bar.close()
        return self.result()
