"""The volume check's pieces against the implementations they replace, side by side in one run
(on demand: ``python benchmarks/arm_volume.py [--quick] [--threads 1]``).

Each row times the same computation two ways on the same inputs (median of ``--repeats``
calls, the two ways taking turns call by call, one thread by default) and prints their ratio and
the largest difference of the results:

1. the robot's capsules placed at ``400 x 100`` float64 configurations: ``pytorch_kinematics``'
   frames + ``capsule_segments`` against the compiled chain (``ArmKinematics.carry_points``);
2. their gap to the can: ``segment_cylinder_distance`` on every capsule and step against the
   pruned ``capsules_gap`` (bit-equal: the difference must print 0);
3. the whole volume success check, both ways (``task.success`` against the frames' path);
4. the end link's Jacobian and pose of 2000 configurations: ``pytorch_kinematics`` against
   ``ArmKinematics.jacobian_pose``;
5. the detour priors' IK of 200 paths x 100 steps: ``follow_path`` with the chain's Jacobian
   against the compiled one;
6. the volume gap and table check of as many trajectories as the detour priors check (2,000 x 100
   steps, float64): in one call against ``joints_clearance``'s pieces (bit-equal: 0);
7. the volume objective (``end_volume_near``) on one of the loop's cost pieces (700 trajectories x
   25 cost steps, float32), the compiled chain's ``cos``/``sin`` rows taken from the transposed
   joints as they come (strided: every product with a row gathers) against contiguous rows and
   no copies where every point moves (:class:`StridedRows`, the code before; bit-equal: 0);
8. the same objective with the joints' ``cos``/``sin`` rows computed for each frame's capsules
   (:class:`TrigPerFrame`, the code before) against once, passed to both (bit-equal: 0).

``--quick``: small sizes (a check that the script runs, not a measurement).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from protorch.robots import ArmKinematics, capsule_segments
from protorch.tasks import ArmReachTask
from protorch.tasks.arm.collision import (
    CLEARANCE_CHUNK,
    above_table,
    capsule_ends,
    capsules_gap,
    end_volume_near,
    joints_clearance,
)
from protorch.tasks.arm.demos import detour_paths, follow_path
from protorch.tasks.arm.geometry import segment_cylinder_distance


def timed(old, new, repeats: int):
    """``(median seconds, result)`` of ``old`` and of ``new``: ``repeats`` calls each after one
    warm-up call, taking turns (``old`` first on even repeats, ``new`` first on odd ones), so that
    on a machine with other work both see the same load."""
    outs = (old(), new())
    times: tuple[list[float], list[float]] = ([], [])
    for i in range(repeats):
        for j in (0, 1) if i % 2 == 0 else (1, 0):
            t0 = time.perf_counter()
            (old, new)[j]()
            times[j].append(time.perf_counter() - t0)
    return [(statistics.median(t), out) for t, out in zip(times, outs)]


def diff(a, b) -> float:
    if isinstance(a, tuple):
        return max(diff(x, y) for x, y in zip(a, b))
    if a.dtype == torch.bool:
        return float((a != b).sum())
    return float((a.double() - b.double()).abs().max())


class StridedRows(ArmKinematics):
    """The compiled chain as it was before its ``cos``/``sin`` rows were made contiguous (row 7):
    the
    rows of the transposed joints ``(J, P)`` as they come (each a stride-``J`` view), and the
    carried
    points copied back into their rows at every joint."""

    def ee_position(self, q):
        qt = (
            self.check_joints(q, finite=False).reshape(-1, self.num_joints).T
        )  # (J, P), strided rows
        c, s = torch.cos(qt), torch.sin(qt)
        x, y, z = (torch.full_like(c[0], v) for v in self._tail)
        for j in range(self.num_joints - 1, -1, -1):
            x, y = c[j] * x - s[j] * y, s[j] * x + c[j] * y
            x, y, z = self._affine(j, x, y, z)
        return torch.stack([x, y, z], -1).reshape(*q.shape[:-1], 3)

    def ee_frame_rows(self, q, trig=None):  # trig ignored: the rows are taken strided here
        qt = self.check_joints(q, finite=False).reshape(-1, self.num_joints).T
        c, s = torch.cos(qt), torch.sin(qt)
        tail = torch.tensor(self._maps[-1], dtype=q.dtype, device=q.device)
        x, y, z = tail.T[:, :, None].expand(4, 3, qt.shape[1]).unbind(1)  # (4, P)
        origin = torch.tensor([[0.0], [0.0], [0.0], [1.0]], dtype=q.dtype, device=q.device)
        for j in range(self.num_joints - 1, -1, -1):
            x, y = c[j] * x - s[j] * y, s[j] * x + c[j] * y
            x, y, z = self._affine(j, x, y, z, translate=origin)
        return x, y, z

    def _carry_rows(self, q, pts, after, functional=False, trig=None):
        qt = q.reshape(-1, self.num_joints).T
        c, s = torch.cos(qt), torch.sin(qt)
        x, y, z = (pts[:, i, None].expand(-1, qt.shape[1]).clone() for i in range(3))  # (M, P)
        for k, lo in reversed(list(enumerate(after))):
            if lo < pts.shape[0]:
                xs, ys = c[k] * x[lo:] - s[k] * y[lo:], s[k] * x[lo:] + c[k] * y[lo:]
                x[lo:], y[lo:], z[lo:] = self._affine(k, xs, ys, z[lo:])
        return x, y, z


class TrigPerFrame(ArmKinematics):
    """The compiled chain as :func:`end_volume_near` used it before (row 8): the ``cos``/``sin``
    rows
    of the joints computed afresh for each frame's capsules instead of once and passed on."""

    def ee_frame_rows(self, q, trig=None):
        return super().ee_frame_rows(q)

    def carry_points_rows(self, q, plan, *, functional=False, trig=None):
        return super().carry_points_rows(q, plan, functional=functional)


def row(name: str, old, new, repeats: int) -> None:
    (t_old, r_old), (t_new, r_new) = timed(old, new, repeats)
    print(
        f"{name:52s} {1e3 * t_old:9.1f} ms {1e3 * t_new:9.1f} ms {t_old / t_new:6.1f}x   "
        f"largest difference {diff(r_old, r_new):.1e}",
        flush=True,
    )


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes: a check that the script runs")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per row (median)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    n, steps, jac_n, paths = (20, 10, 50, 4) if a.quick else (400, 100, 2000, 200)
    task = ArmReachTask(collision="volume")
    kin, caps = task.kinematics, task.robot.capsule_list()
    gen = torch.Generator().manual_seed(0)
    q = task.start_config() + 0.3 * torch.randn(
        n, steps, kin.num_joints, generator=gen, dtype=torch.float64
    )
    env = task.sample_envs(n, gen)  # (n, 4)
    a_c, b_c = capsule_ends(kin, q, task.capsule_plan)  # (n, T, C, 3)
    r = task.capsule_radii

    def frames_capsules():
        a_f, b_f, _ = capsule_segments(kin.frames(q), kin.frame_names, caps)
        return a_f, b_f

    def full_gap():
        d = (
            segment_cylinder_distance(
                a_c, b_c, env[:, None, None, :2], task.can_radius, 0.0, task.can_height
            )
            - r
        )
        return d.flatten(-2).amin(-1)

    # the success check through pytorch_kinematics' frames, as before the compiled path
    def frames_success():
        frames = kin.frames(q)
        ee = frames[..., -1, :3, 3]
        ok_start = (ee[..., 0, :] - task.start_position()).norm(dim=-1) <= task.start_tol
        ok_goal = (ee[..., -1, :] - task.goal_point(env)).norm(dim=-1) <= task.goal_tol
        clear = task.frames_gap(frames, env) > task.margin
        return ok_start & ok_goal & clear & kin.within_limits(q).all(-1) & above_table(task, frames)

    print(f"{'':52s} {'before':>12s} {'now':>12s} {'ratio':>7s}   (one thread: {a.threads})")
    row(
        f"capsules placed, {n} x {steps} float64",
        frames_capsules,
        lambda: capsule_ends(kin, q, task.capsule_plan),
        a.repeats,
    )
    row(
        "their gap to the can (exact search / pruned)",
        full_gap,
        lambda: capsules_gap(a_c, b_c, r, env, task.can_radius, task.can_height),
        a.repeats,
    )
    row("the volume success check", frames_success, lambda: task.success(q, env), a.repeats)
    qj = task.start_config() + 0.5 * torch.randn(
        jac_n, kin.num_joints, generator=gen, dtype=torch.float64
    )
    row(
        f"Jacobian and pose, {jac_n} configurations",
        lambda: kin.chain.jacobian(qj, ret_eef_pose=True),
        lambda: kin.jacobian_pose(qj),
        a.repeats,
    )
    detours = detour_paths(task, task.sample_envs(paths, gen), 0, 0.18, 100)  # (paths, 100, 3)
    row(
        f"detour IK, {paths} paths x 100 steps",
        lambda: follow_path(task, detours)[0],
        lambda: follow_path(task, detours, compiled=True)[0],
        max(1, a.repeats // 5),
    )
    many = 200 if a.quick else 2000
    chunk = (
        64 * steps if a.quick else CLEARANCE_CHUNK
    )  # --quick: pieces of 64, so that the small check is cut too
    q_many = task.start_config() + 0.3 * torch.randn(
        many, steps, kin.num_joints, generator=gen, dtype=torch.float64
    )
    env_many = task.sample_envs(many, gen)
    row(
        f"volume gap and table, {many} x {steps} (one call / pieces)",
        lambda: joints_clearance(task, q_many, env_many, chunk=None),
        lambda: joints_clearance(task, q_many, env_many, chunk=chunk),
        a.repeats,
    )
    pieces = 20 if a.quick else 700  # one of the loop's cost pieces (loop/phases.py: cost_chunks)
    q_obj = (
        task.start_config()
        + 0.3 * torch.randn(pieces, 25, kin.num_joints, generator=gen, dtype=torch.float64)
    ).float()  # (pieces, 25, J): the objectives' 25 cost steps, float32 as the loop samples
    env_obj = task.sample_envs(pieces, gen).float()
    strided = StridedRows(kin.urdf_text, end_link=kin.end_link)
    row(
        f"volume objective, {pieces} x 25 float32 (strided / rows)",
        lambda: end_volume_near(strided, q_obj, env_obj, task.end_capsules, task.can_height),
        lambda: end_volume_near(kin, q_obj, env_obj, task.end_capsules, task.can_height),
        10 * a.repeats,
    )
    per_frame = TrigPerFrame(kin.urdf_text, end_link=kin.end_link)
    row(
        f"volume objective, {pieces} x 25 float32 (trig per frame / once)",
        lambda: end_volume_near(per_frame, q_obj, env_obj, task.end_capsules, task.can_height),
        lambda: end_volume_near(kin, q_obj, env_obj, task.end_capsules, task.can_height),
        10 * a.repeats,
    )


if __name__ == "__main__":
    main()
