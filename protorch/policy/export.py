"""The program :meth:`protorch.policy.policy.Policy.export` writes: a policy's per-call computation
(the map's means of every class at an environment, the class choice at the start of a motion, the
reference at a time) with static shapes only, for ``torch.export``."""

from __future__ import annotations

import io
from pathlib import Path

import torch
from torch import Tensor

from ..control.arm_choice import rest_scores
from ..data.files import atomic_write_bytes
from ..gp.kernels import rbf
from ..tasks.arm.collision import capsule_ends
from ..tasks.arm.geometry import segment_cylinder_distance
from .means import basis3

__all__ = ["ExportProgram", "save_program", "static_gaps", "write_program"]


def static_gaps(task, q: Tensor, env: Tensor) -> Tensor:
    """The arm's gap to the can at each configuration ``q (..., J)``: ``(...)``, the numbers of
    :meth:`~protorch.tasks.ArmReachTask.can_gap` of one step, with static shapes only (every
    capsule searched, the same numbers as the task's pruned search; the skeleton's placed by the
    compiled chain, equal to the task's to round-off)."""
    if getattr(task, "capsule_plan", None) is None:  # the skeleton
        return (
            task.skeleton_distance(task.kinematics.skeleton(q)[..., None, :, :], env)
            - task.can_radius
        )
    a, b = capsule_ends(
        task.kinematics, q, task.capsule_plan, functional=True
    )  # (..., C, 3), no slice written in place
    axis = env[..., None, 0:2]  # (..., 1, 2)
    d = segment_cylinder_distance(a, b, axis, task.can_radius, 0.0, task.can_height)  # (..., C)
    return (d - task.capsule_radii.to(d)).amin(-1)


class ExportProgram(torch.nn.Module):
    """:meth:`~protorch.policy.policy.Policy.export`'s computation, ``(env (d,), t ()) -> (q, qd,
    qdd (D,), label ())``,
    written with static shapes only (``torch.export``)."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.p = policy
        m = policy.means
        self.mode = m.mode
        kw = dict(dtype=torch.float64)
        self.register_buffer("labels", policy.labels.clone())
        if m.mode == "nearest":
            for c in range(len(m.E)):
                self.register_buffer(f"E{c}", m.E[c].clone())
                self.register_buffer(f"MU{c}", m.MU[c].clone())
                self.register_buffer(f"VAR{c}", m.VAR[c].clone())
        elif m.mode == "exact":
            self.register_buffer("E_all", m.E_all.clone())
            self.register_buffer("coef", m.coef.clone())
            self.register_buffer("mu0", m.mu0.clone())
            self.register_buffer("mask", m.mask.clone())
        else:
            raise ValueError(
                "export supports maps with nearest_k or the torch backend, not "
                f"{policy.env_map.backend!r} "
                "without nearest_k"
            )
        if policy._arm:
            self.register_buffer("grid", policy._grid.clone().to(**kw))  # (P,)

    def _means(self, env: Tensor) -> Tensor:
        m, out = self.p.means, []
        if self.mode == "exact":
            kq = rbf(env[None], self.E_all, m.alpha)  # (1, M)
            return self.mu0 + (self.mask * kq) @ self.coef  # (K, N)
        for c in range(len(m.E)):
            E, MU, VAR, k = (
                getattr(self, f"E{c}"),
                getattr(self, f"MU{c}"),
                getattr(self, f"VAR{c}"),
                m.k[c],
            )
            d2 = (torch.cdist(env[None], E, compute_mode="donot_use_mm_for_euclid_dist") ** 2)[
                0
            ]  # (Mg,) as sq_dist
            idx = torch.sort(d2, stable=True).indices[
                :k
            ]  # (k,) ties by insertion order, as the map
            Es, MUs, VARs = E[idx], MU[idx], VAR[idx]  # (k, d), (k, N), (k, N)
            A = rbf(Es, Es, m.alpha)[None].expand(MU.shape[1], k, k) + torch.diag_embed(
                VARs.T
            )  # (N, k, k)
            L = torch.linalg.cholesky(A)  # (N, k, k)
            mu0 = MUs.mean(0)  # (N,)
            coef = torch.cholesky_solve((MUs - mu0).T[..., None], L)[..., 0]  # (N, k)
            kq = rbf(env[None], Es, m.alpha)[0]  # (k,)
            out.append(mu0 + coef @ kq)  # (N,)
        return torch.stack(out)  # (K, N)

    def forward(self, env: Tensor, t: Tensor):
        p = self.p
        z = torch.clamp(t / p.duration, max=1.0)  # ()
        means = self._means(env)  # (K, N)
        k = means.shape[0]
        if k == 1:
            c = torch.zeros((), dtype=torch.long)
        elif (
            p._arm
        ):  # rest_scores for every count of the grid's phases still ahead, the right one taken
            task, grid = p.task, self.grid
            pos = means.unflatten(-1, (p._d, p._kb)) @ basis3(p._P, z)[0]  # (K, D)
            ee = task.ee_path(pos)[:, None]  # (K, 1, 3)
            n = grid.shape[0]
            table = torch.stack(
                [
                    rest_scores(task, p._P, means[:, None], env[None], ee, grid[n - r :])[:, 0]
                    for r in range(n + 1)
                ]
            )  # (P + 1, K) scores with the last r phases ahead
            ahead = (grid > z).sum()  # ()
            scores = table[ahead]  # (K,)
            if (
                p.check
            ):  # rest_blocked: each class's own mean now, then its mean at the phases ahead
                traj = p._phi_grid @ means.unflatten(-1, (p._d, p._kb)).transpose(1, 2)  # (K, P, D)
                g = static_gaps(task, traj, env.expand(k, n, env.shape[-1]))  # (K, P)
                tail = torch.flip(
                    torch.cummin(torch.flip(g, [-1]), -1).values, [-1]
                )  # (K, P) min over phases i..P-1
                tail = torch.cat([tail, torch.full_like(tail[:, :1], torch.inf)], -1)  # (K, P + 1)
                gap = torch.minimum(
                    static_gaps(task, pos, env.expand(k, env.shape[-1])),
                    tail.index_select(1, (n - ahead)[None])[:, 0],
                )  # (K,)
                blocked = gap <= task.margin
                stuck = blocked.all()  # every class blocked: the largest clearance (checked_choice)
                scores = torch.where(blocked & ~stuck, torch.inf, scores)
                c = torch.where(stuck, torch.argmax(gap), torch.argmin(scores))
            else:
                c = torch.argmin(scores)
        else:
            scores = p.task.costs(p._P.trajectory(means), env.expand(k, -1)).sum(-1)  # (K,)
            c = torch.argmin(scores)
        w = means[c]  # (N,)
        phi = basis3(p._P, z) * p._scale  # (3, K)
        moving = (z < 1.0).to(torch.float64)
        phi = torch.cat(
            [phi[:1], phi[1:] * moving]
        )  # held at the end: no velocity, no acceleration
        state = phi @ w.unflatten(-1, (p._d, p._kb)).T  # (3, D)
        return state[0], state[1], state[2], self.labels[c]


def write_program(policy, path: Path, aoti: bool = False) -> Path:
    """:meth:`~protorch.policy.policy.Policy.export`: trace :class:`ExportProgram` with
    ``torch.export`` (at the map's first environment and mid-motion) and write it to ``path``
    atomically; ``aoti``: compiled by AOTInductor into a package first (its shared library is
    built for this machine's kind of processor, and for the torch version that built it)."""
    program = ExportProgram(policy)
    args = (
        policy.env_map.E[0].to(torch.float64),
        torch.tensor(0.5 * policy.duration, dtype=torch.float64),
    )
    return save_program(
        program,
        args,
        path,
        aoti,
        "this policy",
        "; a task's costs must be traceable (no Python branches on tensor values)",
    )


def save_program(
    module: torch.nn.Module, args: tuple, path: Path, aoti: bool, what: str, hint: str = ""
) -> Path:
    """``module`` traced by ``torch.export`` at ``args`` and written to ``path`` atomically
    (``aoti``: compiled by AOTInductor into a package first); a module that cannot be traced is
    one ``RuntimeError`` naming ``what`` (and ``hint``)."""
    try:
        ep = torch.export.export(module, args, strict=False)
    except Exception as exc:
        raise RuntimeError(
            f"torch.export could not trace {what} ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}){hint}"
        ) from exc
    buf = io.BytesIO()
    if aoti:
        torch._inductor.aoti_compile_and_package(ep, package_path=buf)
    else:
        torch.export.save(ep, buf)
    return atomic_write_bytes(path, buf.getvalue())
