"""Where an arm works, measured from its kinematics: :func:`hand_down_layout` gives the home pose
(hand down above the workspace) and the workspace (can and target rectangles, table, can size)
of an arm that has none, placed on the arm's own reach as the Panda's are on the Panda's.

The Panda's numbers (``robot=panda``, unchanged) anchor the rule. Its hand, pointing down
10 cm above the table, reaches targets on the ``x`` axis in ``[0.29, 0.80]`` m by the rule below
(span 0.51 m; applied to the Panda, the rule gives the Panda's numbers to 1e-4 m); its home is at
``x = 0.40``, the can in
``[0.50, 0.62] x [-0.12, 0.12]``, the target in ``[0.66, 0.74] x [-0.24, 0.24]``, the table
``[0.2, 0.9] x [-0.5, 0.5]``, the can 0.0375 m in radius and 0.23 m high. For another arm:

1. its size ``s_v = L / L_panda`` (``L``: the summed distances between consecutive frame origins
   from the second moving joint to the end link) sets the working height ``0.10 s_v``, raised
   where the hand's bodies reach farther below the end link than the Panda's do: the end link
   stands at least ``d + 0.0889 s_v`` above the table, ``d`` how far the capsules of the links
   rigid with the end link reach below it with the hand down (:func:`hand_drop`; the Panda's
   0.0111 m, its hand's lowest point 0.0889 m above the table, :data:`PANDA_HAND_LOW`; pybullet's
   KUKA iiwa's link 7 reaches 0.059 m below its frame); the can's
   height is the Panda's 0.23 m times the ratio of the wrists' heights at home (the frame the
   second-to-last joint moves; the Panda's 0.3104 m), so that the wrist passes over the can as
   the Panda's does; where the arm has capsules (:func:`auto_workspace`), the ratio of the lowest
   points of the wrist's capsules instead (:func:`wrist_low`; the Panda's 0.2274 m). The wrist's
   capsules reach about 0.08 to 0.10 m below its frame on the Panda, pybullet's xArm 6 and KUKA
   alike, not in proportion to the arm: a can sized by the frames (the xArm's 0.124 m, the KUKA's
   0.121 m) stood above the bottoms of their wrists' capsules (0.084 m, 0.065 m);
2. the hand-down inverse kinematics (end link's ``z`` down; two hand yaws, 0 and 90 degrees, the one
   reaching the longer interval kept) from the joint limits' middle, continued from neighbour to
   neighbour on a 1 cm lattice along ``+x`` at that height, measures the interval
   ``[r_min, r_max]`` the hand reaches (every link above the table, inside the limits);
3. with ``s = r_max / 0.80``, the home at ``x_h = max(0.40 s, r_min + 0.11 s)`` (the Panda's
   ``0.40``, its ``r_min + 0.11``), every x coordinate mapped linearly so that the Panda's home goes
   to ``x_h`` and its ``r_max`` to this arm's; every y extent and the can's radius scaled by ``s``.

A lattice where the hand reaches no interval of at least 10 cm is refused (``ValueError``).
"""

from __future__ import annotations

import functools
import math

import torch

from ..threads import torch_threads
from .description import capsule_segments
from .ik import ik_seeds, seed_label
from .kinematics import ArmKinematics

__all__ = [
    "PANDA_LAYOUT",
    "PANDA_LENGTH",
    "PANDA_REACH",
    "PANDA_HAND_LOW",
    "PANDA_WRIST_LOW",
    "arm_length",
    "auto_workspace",
    "hand_down_layout",
    "hand_drop",
    "measure_layout",
    "wrist_low",
]

PANDA_REACH = (
    0.29,
    0.80,
)  # m, the Panda's hand-down reach at 0.10 m by this module's rule (its 1 cm lattice)
PANDA_LENGTH = 1.0897  # m, the Panda's L (module docstring), measured on protorch/robots/panda.urdf
# m, the Panda's wrist (the frame its second-to-last joint moves) above the table at home
PANDA_WRIST = 0.3104
# m, the lowest point of the Panda's wrist capsules (link 6's, protorch/robots/panda.yaml) at home
PANDA_WRIST_LOW = 0.2274
# m, the lowest point of the Panda's hand capsules (panda_hand's) at home, the end link 0.10 m up
PANDA_HAND_LOW = 0.0889
_HEIGHT, _CAN_HEIGHT, _CAN_RADIUS = 0.10, 0.23, 0.0375
_HOME_X, _CAN_X, _GOAL_X, _TABLE_X = 0.40, (0.50, 0.62), (0.66, 0.74), (0.2, 0.9)
_CAN_Y, _GOAL_Y, _TABLE_Y = 0.12, 0.24, 0.5
PANDA_LAYOUT = {
    "can_box": ((0.50, 0.62), (-0.12, 0.12)),
    "goal_box": ((0.66, 0.74), (-0.24, 0.24)),
    "table": ((0.2, 0.9), (-0.5, 0.5)),
    "can_radius": _CAN_RADIUS,
    "can_height": _CAN_HEIGHT,
    "reach": (0.30, 0.80),
}  # the shipped robots' workspace (``auto`` with a shipped robot)


def arm_length(kin) -> float:
    """``L``: the summed distances between consecutive frame origins from the second moving
    joint's frame to the end link, at the zero pose (m)."""
    q = torch.zeros(kin.num_joints, dtype=kin.lower.dtype, device=kin.lower.device).clamp(
        kin.lower, kin.upper
    )
    pos = kin.link_positions(q).cpu()  # (F, 3)
    moving = _moving_indices(kin)
    start = moving[1] if len(moving) > 1 else 0
    return float((pos[start + 1 :] - pos[start:-1]).norm(dim=-1).sum())


def _moving_indices(kin) -> list[int]:
    """The indices in ``kin.frame_names`` of the frames a moving (not fixed) joint moves."""
    names = kin.frame_names
    return [
        i
        for i in range(1, len(names))
        if kin.chain.find_frame(names[i]).joint.joint_type != "fixed"
    ]


def _down(yaw: float, dtype) -> torch.Tensor:
    c, s = math.cos(yaw), math.sin(yaw)
    return torch.tensor(
        [[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]], dtype=dtype
    )  # z down, x at yaw


def _sweep(
    kin, xs: torch.Tensor, z: float, rot: torch.Tensor, iters: int = 150, seed=None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Hand-down IK at ``(x, 0, z)`` for each ``x`` ``(N,)`` from ``seed (J,)`` (default: the
    joint limits' middle): ``(q (N, J), ok (N,))``."""
    kw = dict(dtype=kin.lower.dtype, device=kin.lower.device)
    n = xs.shape[0]
    mid = (0.5 * (kin.lower + kin.upper) if seed is None else seed).to(**kw)  # (J,)
    pts = torch.stack([xs, torch.zeros_like(xs), torch.full_like(xs, z)], -1).to(**kw)  # (N, 3)
    rots = rot.to(**kw).expand(n, 3, 3)

    def solve(q0):
        q, err = kin.inverse(pts, q0, rotation=rots, rest=mid, iters=iters, compiled=True)
        pose_rot = kin.ee_pose(q)[..., :3, :3]
        rot_err = (pose_rot - rots).flatten(1).norm(dim=-1)
        above = (kin.link_positions(q)[..., 2:, 2] >= -1e-6).all(-1)
        return q, (err < 1e-3) & (rot_err < 1e-2) & above

    q, ok = solve(mid.expand(n, -1).clone())
    for _ in range(4):  # continuation: a failed point starts from its nearest solved neighbour
        if bool(ok.all()) or not bool(ok.any()):
            break
        idx = torch.arange(n)
        good = idx[ok.cpu()]
        near = good[(idx[:, None] - good[None, :]).abs().argmin(1)]
        q2, ok2 = solve(q[near.to(q.device)].clone())
        better = ok2 & ~ok
        q, ok = torch.where(better[:, None], q2, q), ok | ok2
    return q, ok.cpu()


def _longest_run(ok: torch.Tensor) -> tuple[int, int]:
    best, start, out = 0, None, (0, -1)
    for i, v in enumerate(ok.tolist() + [False]):
        if v and start is None:
            start = i
        elif not v and start is not None:
            if i - start > best:
                best, out = i - start, (start, i - 1)
            start = None
    return out


def auto_workspace(robot) -> tuple[dict, dict | None]:
    """``(values, measured layout or None)``: the workspace ``auto`` stands for (``can_box``,
    ``goal_box``, ``table``, ``can_radius``, ``can_height``, ``reach``): the Panda's numbers for a
    shipped robot (``robot.base`` set), else the arm's measured layout
    (:func:`hand_down_layout`)."""
    if robot.settings.get("base") is not None:
        return dict(PANDA_LAYOUT), None
    layout = robot.found.get("layout")
    if layout is None:
        kin = robot.kinematics()
        layout = hand_down_layout(kin, robot.name, hand_drop(kin, robot.capsules))
    layout = dict(layout)
    low = wrist_low(robot)
    if low is not None:  # the wrist's bodies, not its frame, pass over the can as the Panda's
        layout["wrist_low"] = round(low, 4)
        layout["can_height"] = round(_CAN_HEIGHT * low / PANDA_WRIST_LOW, 4)
    return layout, layout


def wrist_low(robot) -> float | None:
    """The lowest point (m above the table) at ``robot.home`` of the capsules of the wrist: the
    links from the frame the second-to-last moving joint moves up to the last moving joint's (the
    Panda's link 6, :data:`PANDA_WRIST_LOW`); ``None`` where the wrist has no capsules."""
    kin = robot.kinematics()
    names = kin.frame_names
    moving = _moving_indices(kin)
    wrist = set(names[moving[-2] : moving[-1]])
    caps = [c for c in robot.capsule_list() if c.link in wrist]
    if not caps:
        return None
    frames = kin.frames(torch.tensor(robot.home, dtype=kin.lower.dtype, device=kin.lower.device))
    a, b, r = capsule_segments(frames, names, caps)  # (C, 3), (C, 3), (C,)
    return float((torch.minimum(a[:, 2], b[:, 2]) - r.to(a)).min())


def hand_drop(kin, capsules) -> float | None:
    """How far (m) the capsules of the links rigid with the end link (those past the last moving
    joint) reach below the end link's origin when the end link's ``z`` points down (the hand-down
    pose of :func:`measure_layout`, any yaw): ``capsules`` ``{link: (Capsule, ...)}``; negative
    where they stay above it, ``None`` where the hand has no capsules. The Panda's: 0.0111 m."""
    names = kin.frame_names
    moving = _moving_indices(kin)
    hand = set(names[moving[-1] :])
    caps = [c for link in names if link in hand for c in capsules.get(link, ())]
    if not caps:
        return None
    mid = (0.5 * (kin.lower + kin.upper)).clamp(kin.lower, kin.upper)  # (J,): any pose will do
    frames = kin.frames(mid)  # (F, 4, 4)
    a, b, r = capsule_segments(frames, names, caps)  # (C, 3), (C, 3), (C,)
    end = frames[names.index(kin.end_link)]  # (4, 4)
    z_axis, origin = end[:3, 2], end[:3, 3]  # the end link's z, pointing down when held down
    along = torch.stack([(a - origin) @ z_axis, (b - origin) @ z_axis])  # (2, C)
    return float((along.max(0).values + r.to(a)).max())


def hand_down_layout(kin, name: str = "the arm", drop: float | None = None) -> dict:
    """The measured layout of an arm (module docstring), cached per URDF text, end link and
    hand drop (:func:`hand_drop`): :func:`measure_layout`."""
    drop = None if drop is None else round(float(drop), 6)
    return dict(_cached(kin.urdf_text, kin.end_link, name, drop))


@functools.lru_cache(maxsize=8)
def _cached(text: str, end_link: str, name: str, drop: float | None) -> dict:

    with (
        torch.no_grad(),
        torch_threads(1),
    ):  # small batches: one thread (several only wait on each other)
        return measure_layout(ArmKinematics(text, end_link=end_link), name, drop)


def working_height(s_v: float, drop: float | None) -> float:
    """The end link's height above the table (m) on the hand-down lattice: ``0.10 s_v``, or
    higher where the hand reaches farther below the end link than the Panda's (module
    docstring, step 1)."""
    z = _HEIGHT * s_v
    return z if drop is None else max(z, drop + PANDA_HAND_LOW * s_v)


def measure_layout(kin, name: str = "the arm", drop: float | None = None) -> dict:
    """The measured layout of an arm (module docstring): ``{"scale", "height", "reach", "yaw",
    "home", "home_target", "home_residual", "home_seed", "can_box", "goal_box", "table",
    "can_radius", "can_height", "hand_drop"}``, ``drop`` the hand's reach below the end link
    (:func:`hand_drop`, ``None``: no capsules); a ``ValueError`` where the hand reaches no 10 cm
    interval."""
    dtype = kin.lower.dtype
    length = arm_length(kin)
    s_v = length / PANDA_LENGTH
    z = working_height(s_v, drop)
    xs = torch.arange(
        0.02, 1.1 * length + 0.1, 0.01, dtype=torch.float64
    )  # the hand reaches no farther than L
    seeds = ik_seeds(kin.lower.cpu(), kin.upper.cpu())  # (K, J): the middle first
    for k in range(seeds.shape[0]):  # a perturbed seed only where the middle's lattice fails
        best = None
        for yaw in (0.0, math.pi / 2):
            seed = None if k == 0 else seeds[k]
            q, ok = _sweep(kin, xs, z, _down(yaw, dtype), seed=seed)
            lo, hi = _longest_run(ok)
            if best is None or hi - lo > best[1] - best[0]:
                best = (lo, hi, yaw, q)
        if best[1] - best[0] >= 10:
            break
    lo, hi, yaw, q = best
    if hi - lo < 10:
        raise ValueError(
            f"{name} holds its hand down at {z:.3f} m above the table over no interval of 10 cm "
            f"along x (the hand-down inverse kinematics from the joint limits' middle and "
            f"{seeds.shape[0] - 1} perturbed seeds); give robot.home and the workspace "
            "(task.can_box, task.goal_box, task.table)"
        )
    r0, r1 = float(xs[lo]), float(xs[hi])
    scale = r1 / PANDA_REACH[1]
    home_x = max(_HOME_X * scale, r0 + (_HOME_X - PANDA_REACH[0]) * scale)

    def at(x):  # the Panda's home -> home_x, its farthest reach -> r1, linearly
        return round(home_x + (x - _HOME_X) / (PANDA_REACH[1] - _HOME_X) * (r1 - home_x), 4)

    home_x = at(_HOME_X)
    s_h = scale
    i = int((xs - home_x).abs().argmin())
    target = torch.tensor([[home_x, 0.0, z]], dtype=dtype, device=kin.lower.device)
    home, err = kin.inverse(
        target,
        q[i : i + 1].to(kin.lower.device),
        rotation=_down(yaw, dtype)[None].to(target),
        rest=q[i].to(target),
        iters=300,
        tol=1e-9,
    )
    wrist = float(kin.link_positions(home[0])[_moving_indices(kin)[-2], 2])
    return {
        "wrist_height": round(wrist, 4),
        "scale": round(s_v, 4),
        "scale_xy": round(s_h, 4),
        "length": round(length, 4),
        "height": round(z, 4),
        "hand_drop": None if drop is None else round(drop, 4),
        "reach": [round(r0, 4), round(r1, 4)],
        "yaw": yaw,
        "home": [float(v) for v in home[0].tolist()],
        "home_target": [home_x, 0.0, round(z, 4)],
        "home_residual": float(err[0]),
        "home_seed": f"{seed_label(k, seeds)}, continued along the reach lattice",
        "can_box": [
            [at(_CAN_X[0]), at(_CAN_X[1])],
            [round(-_CAN_Y * s_h, 4), round(_CAN_Y * s_h, 4)],
        ],
        "goal_box": [
            [at(_GOAL_X[0]), at(_GOAL_X[1])],
            [round(-_GOAL_Y * s_h, 4), round(_GOAL_Y * s_h, 4)],
        ],
        "table": [
            [at(_TABLE_X[0]), at(_TABLE_X[1])],
            [round(-_TABLE_Y * s_h, 4), round(_TABLE_Y * s_h, 4)],
        ],
        "can_radius": round(_CAN_RADIUS * s_h, 4),
        "can_height": round(_CAN_HEIGHT * wrist / PANDA_WRIST, 4),
    }
