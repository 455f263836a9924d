"""Re-judge a run's physics episodes independently of the run.

``python benchmarks/replay_physics.py RUN_DIR`` loads ``RUN_DIR/physics/episodes.npz`` (the joint
positions every control step, the can and the target, the run's verdicts) and recomputes, for
every episode and every recorded instant, with its own means:

* the Panda's link frames from the published DH parameters (:data:`PANDA_DH` below,
  flange and hand offsets) in numpy, not through the URDF, pytorch_kinematics or MuJoCo;
* the link capsules (``PANDA_CAPSULES``) against the can as a solid cylinder of the recorded
  radius and height, by dense point sampling: points every millimetre along each capsule's
  segment, each point's exact distance to the cylinder minus the capsule's radius (no segment
  distance formula of protorch's is used);
* the capsules of the moving links against the table top, the tool centre point against the
  final target, the joints against their limits.

It prints, per test (held-out, moving), how many episodes the run called successes and whether
every one of them keeps the arm's volume out of the can, above the table, within the limits and
on the target; and, for the episodes MuJoCo saw touching the can, the replayed depth. Exit
status 1 when a success is contradicted.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from protorch.robots import load_robot

PANDA = load_robot("panda")
PANDA_LIMITS = tuple(zip(PANDA.lower, PANDA.upper))
PANDA_CAPSULES, PANDA_BASE_LINKS = PANDA.capsule_list(), PANDA.base_links
# Franka Emika's published Craig (modified) DH parameters, one row per joint: (a_{i-1} [m], d_i [m],
# alpha_{i-1} [rad]); the flange's d after joint 7; the hand's yaw about the flange's z, then the
# TCP
# along z. The independent reference the URDF is checked against (its header comment lists them).
PANDA_DH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -1.5707963267948966),
    (0.0, 0.316, 1.5707963267948966),
    (0.0825, 0.0, 1.5707963267948966),
    (-0.0825, 0.384, -1.5707963267948966),
    (0.0, 0.0, 1.5707963267948966),
    (0.088, 0.0, 1.5707963267948966),
)
PANDA_FLANGE = 0.107
PANDA_TCP = (-0.7853981633974483, 0.1034)

TOL = 1e-4  # m: what the replay may disagree with MuJoCo's contact test by (sampling, round-off)


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    out = np.zeros(np.shape(a) + (4, 4))
    out[..., 0, 0] = out[..., 3, 3] = 1.0
    out[..., 1, 1], out[..., 1, 2], out[..., 2, 1], out[..., 2, 2] = c, -s, s, c
    return out


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    out = np.zeros(np.shape(a) + (4, 4))
    out[..., 2, 2] = out[..., 3, 3] = 1.0
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    return out


def _trans(x: float, z: float) -> np.ndarray:
    out = np.eye(4)
    out[0, 3], out[2, 3] = x, z
    return out


def dh_frames(q: np.ndarray) -> dict[str, np.ndarray]:
    """Every link frame of the Panda at ``q (..., 7)`` from Craig's DH parameters: ``{name: (...,
    4, 4)}``."""
    frames = {"panda_link0": np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4))}
    t = frames["panda_link0"]
    for i, (a, d, alpha) in enumerate(PANDA_DH):
        fixed = _rot_x(np.float64(alpha)) @ _trans(a, d)
        t = t @ fixed @ _rot_z(q[..., i])
        frames[f"panda_link{i + 1}"] = t
    frames["panda_link8"] = t @ _trans(0.0, PANDA_FLANGE)
    frames["panda_hand"] = frames["panda_link8"] @ _rot_z(np.float64(PANDA_TCP[0]))
    frames["panda_hand_tcp"] = frames["panda_hand"] @ _trans(0.0, PANDA_TCP[1])
    return frames


def cylinder_distance(p: np.ndarray, axis: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Signed distance of points ``p (..., 3)`` to the solid cylinder over ``axis (..., 2)`` from
    ``z = 0`` to ``height`` (negative inside)."""
    rho = np.linalg.norm(p[..., :2] - axis, axis=-1) - radius
    z = p[..., 2]
    below, above = -z, z - height
    out_r, out_z = np.maximum(rho, 0.0), np.maximum(np.maximum(below, above), 0.0)
    outside = np.hypot(out_r, out_z)
    inside = np.maximum(np.maximum(rho, below), above)  # <= 0 when inside
    return np.where((rho > 0) | (below > 0) | (above > 0), outside, inside)


def capsule_points(
    frames: dict[str, np.ndarray], step: float = 1e-3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``step`` along every capsule's segment: ``points (..., P, 3)``, their capsule's
    radius ``(P,)`` and whether it is on a moving link ``(P,)``."""
    pts, radii, moving = [], [], []
    for c in PANDA_CAPSULES:
        a, b = np.array(c.a), np.array(c.b)
        n = max(2, int(math.ceil(np.linalg.norm(b - a) / step)) + 1)
        local = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)  # (n, 3)
        f = frames[c.link]
        pts.append(np.einsum("...ij,nj->...ni", f[..., :3, :3], local) + f[..., None, :3, 3])
        radii.append(np.full(n, c.radius))
        moving.append(np.full(n, c.link not in PANDA_BASE_LINKS))
    return np.concatenate(pts, -2), np.concatenate(radii), np.concatenate(moving)


def replay(path: Path) -> dict:
    """Every episode of ``episodes.npz`` re-judged (module docstring): per test, the counts."""
    with np.load(path) as f:
        ep = {k: f[k] for k in f.files}
    lo, hi = np.array(PANDA_LIMITS).T
    out = {}
    for name, sel in (("held-out", ~ep["moving"]), ("moving", ep["moving"])):
        idx = np.flatnonzero(sel)
        if not idx.size:
            continue
        gaps, table, limits, goal = [], [], [], []
        for i in idx:
            q = ep["q"][i]  # (T+1, 7)
            frames = dh_frames(q)
            pts, r, moving = capsule_points(frames)  # (T+1, P, 3)
            d = (
                cylinder_distance(
                    pts, ep["can"][i][:, None, :], float(ep["can_radius"]), float(ep["can_height"])
                )
                - r
            )
            gaps.append(d.min())
            table.append((pts[..., moving, 2] - r[moving]).min())
            limits.append(bool(((q >= lo) & (q <= hi)).all()))
            tcp = frames["panda_hand_tcp"][-1, :3, 3]
            target = np.array([*ep["target"][i, -1], float(ep["ee_height"])])
            goal.append(float(np.linalg.norm(tcp - target)))
        gaps, table, goal, limits = (
            np.array(gaps),
            np.array(table),
            np.array(goal),
            np.array(limits),
        )
        ok = ep["success"][idx]
        touched = ep["failure_can_contact"][idx]
        contradicted = ok & (
            (gaps <= -TOL) | (table <= -TOL) | ~limits | (goal > float(ep["goal_tol"]) + TOL)
        )
        out[name] = {
            "episodes": int(idx.size),
            "successes": int(ok.sum()),
            "contradicted": int(contradicted.sum()),
            "min_gap_of_successes": float(gaps[ok].min()) if ok.any() else None,
            "mujoco_can_contacts": int(touched.sum()),
            "replayed_depth_where_mujoco_touched": float(gaps[touched].min())
            if touched.any()
            else None,
            "touched_but_replay_clear_by_1mm": int((touched & (gaps > 1e-3)).sum()),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run_dir", type=Path)
    a = p.parse_args(argv)
    res = replay(a.run_dir / "physics" / "episodes.npz")
    bad = 0
    for name, r in res.items():
        print(
            f"{name}: {r['episodes']} episodes, {r['successes']} physics successes, "
            f"{r['contradicted']} contradicted "
            f"by the replay (smallest capsule-can gap of a success {r['min_gap_of_successes']}); "
            "MuJoCo saw the can "
            f"touched in {r['mujoco_can_contacts']}, replayed deepest "
            f"{r['replayed_depth_where_mujoco_touched']}, "
            f"clear by > 1 mm at every control instant in {r['touched_but_replay_clear_by_1mm']}"
        )
        bad += r["contradicted"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
