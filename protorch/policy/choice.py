"""The class choice of :class:`~protorch.policy.policy.Policy` (its module docstring, item 2), as
a mixin: the scores, the decision with hysteresis and the plan check, and what a motion at a fixed
environment starts with."""

from __future__ import annotations

import bisect
import contextlib
import math

import torch
from torch import Tensor

from ..control.arm_choice import checked_choice, hysteresis_choice, rest_scores

__all__ = ["ClassChoice"]


class ClassChoice:
    """:class:`~protorch.policy.policy.Policy`'s class choice (the policy's attributes: its task,
    ProMP, means, the objectives' grid, the motion's state ``_m``)."""

    def _scores(
        self, means: Tensor, env: Tensor, z: float, q: Tensor | None, phi: Tensor
    ) -> Tensor:
        """Each class's score ``(K,)`` (module docstring, item 2); ``phi (K,)`` the
        basis at ``z``."""
        task = self.task
        if not self._arm:
            return task.costs(self._P.trajectory(means), env.expand(means.shape[0], -1)).sum(
                -1
            )  # (K,)
        k = means.shape[0]
        w = means.view(k, self._d, self._kb)  # (K, D, Kb)
        ahead = len(self._grid_list) - bisect.bisect_right(
            self._grid_list, z
        )  # the objectives' phases after z
        now = (
            w @ phi if q is None else q[None]
        )  # (K, D) the arm on each class's own mean now, or (1, D) measured
        traj = self._phi_grid[len(self._grid_list) - ahead :] @ w.transpose(
            1, 2
        )  # (K, P', D) the rest of each mean
        ee = self._ee(
            torch.cat([now, traj.reshape(-1, self._d)])
        )  # (K or 1 + K P', 3) one kinematics pass
        start, path = ee[: now.shape[0], None], ee[now.shape[0] :].view(k, 1, ahead, 3)
        rest = self._grid[len(self._grid_list) - ahead :]  # (P',)
        return rest_scores(task, self._P, means[:, None], env[None], start, rest, path=path)[
            :, 0
        ]  # (K,)

    def choose(
        self,
        env: Tensor,
        t: float,
        q: Tensor | None = None,
        point: list[float] | None = None,
        phi: Tensor | None = None,
        qd: Tensor | None = None,
    ) -> tuple[int, Tensor]:
        """The class row (into :attr:`labels`) tracked at ``t`` and its mean weights ``(1, N)``:
        a decision (every class asked, scored, hysteresis) at the first call and whenever ``t``
        enters a new ``decision_dt`` slot; between decisions only the current class is asked (a
        call that solved no set of its own also readies a set for its next swap, or every
        ``decision_dt / 4`` and right before a decision brings another class's set up to date).
        ``point``: ``env.tolist()``; ``phi (3, K)``: :meth:`basis_at` ``t``."""
        z = min(t / self.duration, 1.0)
        means = self.means
        if point is None:
            point = env.tolist()
        if len(self._label_list) == 1:
            self._m.current = 0
            return 0, means.mean(0, env, point)
        if self.task is None:
            raise ValueError(
                f"this map has the classes {self.labels.tolist()}: choosing one needs the run's "
                "task "
                "(protorch.load(run_dir) of a run folder with its config.yaml)"
            )
        slot = math.floor(t / self.decision_dt + 1e-9)
        m = self._m
        if m.current is not None and slot <= m.slot:
            solved = means.misses
            w = means.mean(m.current, env, point)
            # a call that solved nothing does one thing more: the tracked set's inverses
            # (ClassMeans.prepare),
            # or another class's (then its set brought up to date; first on the call before a
            # decision)
            before = (m.slot + 1) * self.decision_dt - t <= 1.5 * (
                t - m.t
            )  # by the loop's last interval
            if (
                means.mode != "nearest"
                or means.misses != solved
                or (not before and means.prepare(m.current))
            ):
                return m.current, w
            if before or t - m.fresh >= self._refresh_dt:
                others = [c for c in range(len(self._label_list)) if c != m.current]
                c = others[m.turn % len(others)]
                if before or not means.prepare(c):
                    means.neighbour_set(c, env, point)
                    m.turn += 1
                    m.fresh = t if m.turn % len(others) == 0 else m.fresh
            return m.current, w
        every = means(env)  # (K, N)
        phi = self.basis_at(t) if phi is None else phi
        c = self._decide(every, env, z, q, qd, phi, m.current, self._memo)
        m.current = c
        m.slot, m.fresh = slot, t
        return c, every[c : c + 1]

    def _decide(
        self, every: Tensor, env: Tensor, z: float, q, qd, phi: Tensor, current: int | None, memo
    ) -> int:
        """A class decision (module docstring, item 2): ``every (K, N)`` the classes' means at
        ``env``, ``phi (3, K)`` the basis at ``z``, ``current`` the class tracked (``None``:
        none)."""
        scores = self._scores(every, env, z, q, phi[0])[:, None]  # (K, 1)
        cur = None if current is None else torch.tensor([current])
        if self.check and self._arm:  # the moving test's checked choice
            k = every.shape[0]
            now = (
                q[None] if q is not None else (every.view(k, self._d, self._kb) @ phi[0])[:, None]
            )  # (1, D) | (K, 1, D)
            rest = self._grid[bisect.bisect_right(self._grid_list, z) :]  # (P',) the phases after z
            v = (
                None if q is None else (torch.zeros_like(q) if qd is None else qd)[None]
            )  # (1, D) the arm's velocity
            return int(
                checked_choice(
                    self.task,
                    self._P,
                    every[:, None],
                    env[None],
                    now,
                    z,
                    rest,
                    scores,
                    cur,
                    self.switch_margin,
                    v,
                    self._follow,
                    self.switch_clearance,
                    memo,
                )[0]
            )
        return int(hysteresis_choice(scores, cur, self.switch_margin)[0])

    def first_class(self, env) -> int:
        """The class row (into :attr:`labels`) a motion at the fixed environment ``env (d,)`` starts
        with: :meth:`reference`'s first decision after :meth:`reset` with ``q=None`` (the motion's
        whole objectives from each class's own start, with ``check`` the plan check of each
        class's mean). Leaves the motion under way as it is (with ``planner="thread"`` it waits
        for the planner's step)."""
        env = self._check(env, 0.0, None)[0]
        if len(self._label_list) == 1:
            return 0
        if self.task is None:
            raise ValueError(
                f"this map has the classes {self.labels.tolist()}: choosing one needs the run's "
                "task "
                "(protorch.load(run_dir) of a run folder with its config.yaml)"
            )
        lock = self._planner.lock if self._planner is not None else contextlib.nullcontext()
        with lock, torch.inference_mode():
            every = self.means(env)  # (K, N)
            return self._decide(every, env, 0.0, None, None, self.basis_at(0.0), None, None)
