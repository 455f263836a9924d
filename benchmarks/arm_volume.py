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
   steps, float64): in one call against ``joints_clearance``'s pieces (bit-equal: 0).

``--quick``: small sizes (a check that the script runs, not a measurement).
"""

from __future__ import annotations

import argparse
import statistics

import torch
from _timing import turns

from protorch.robots import capsule_segments
from protorch.tasks import ArmReachTask
from protorch.tasks.arm.collision import (
    CLEARANCE_CHUNK,
    above_table,
    capsule_ends,
    capsules_gap,
    joints_clearance,
)
from protorch.tasks.arm.demos import detour_paths, follow_path
from protorch.tasks.arm.geometry import segment_cylinder_distance


def diff(a, b) -> float:
    if isinstance(a, tuple):
        return max(diff(x, y) for x, y in zip(a, b))
    if a.dtype == torch.bool:
        return float((a != b).sum())
    return float((a.double() - b.double()).abs().max())


def row(name: str, old, new, repeats: int) -> None:
    (t_old, t_new), (r_old, r_new) = turns([old, new], repeats)
    t_old, t_new = statistics.median(t_old), statistics.median(t_new)
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


if __name__ == "__main__":
    main()
