"""Forward kinematics of a serial arm loaded from a URDF with ``pytorch_kinematics``.

:class:`ArmKinematics` wraps ``pytorch_kinematics.build_serial_chain_from_urdf`` as a torch module
(the chain follows ``.to(device, dtype)``) and gives, for joint tensors of any leading shape
``(..., J)`` (e.g. ``(S, T, 7)``: ``S`` sampled trajectories of ``T`` steps) in one call:

* :meth:`~ArmKinematics.frames`: every frame of the chain, root to end link, ``(..., F, 4, 4)``
  (``pytorch_kinematics``' batched ``forward_kinematics_tensor``);
* :meth:`~ArmKinematics.link_positions`: their origins ``(..., F, 3)``, the arm's skeleton;
* :meth:`~ArmKinematics.ee_position`: the end link's origin ``(..., 3)`` by a compiled path (below);
* :meth:`~ArmKinematics.jacobian`: the end link's geometric Jacobian ``(..., 6, J)``.

The compiled end-effector path is what makes the arm experiment's cost evaluation cheap (about
10^9 end-effector positions over a paper-scale loop). From the chain's own static offsets and
joint axes it folds every revolute joint into a rotation about ``z`` between two fixed affine
maps, then carries the end point backwards through the chain with elementwise tensor operations
(``x' = c x - s y``, ``y' = s x + c y`` per joint, then the fixed map, whose entries within
``1e-7`` of 0 or +-1, the float32 parse of ``pi / 2`` rotations, are snapped so they cost
nothing). It agrees with the full FK to round-off and is about 100 times faster on a CPU.
"""

from __future__ import annotations

import bisect
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import torch
from torch import Tensor, nn

from ..checks import check_tensor
from .ik import inverse_kinematics
from .urdf import default_chain, parse_urdf, read_urdf, urdf_links

__all__ = ["ArmKinematics", "PointPlan", "parse_urdf", "urdf_links"]

_SNAP = 1e-7


class PointPlan(NamedTuple):
    """Points fixed on the arm's links, prepared for :meth:`ArmKinematics.carry_points`."""

    # (M, 3) float64: each point in the frame after its last joint's rotation, ordered by that joint
    start: Tensor
    after: list  # per joint k, the index of the first point (in that order) after joint k
    back: Tensor | None  # the permutation back to the caller's order (None: already in it)


def _joint_limits_from_xml(
    text: str, names: list[str]
) -> tuple[list[float], list[float], list[float]]:
    root = ET.fromstring(text)
    by_name = {j.get("name"): j for j in root.iter("joint")}
    lower, upper, vel = [], [], []
    for n in names:
        lim = by_name[n].find("limit")
        if lim is None or lim.get("lower") is None or lim.get("upper") is None:
            raise ValueError(f"joint {n!r} of the URDF has no <limit lower=... upper=...>")
        lower.append(float(lim.get("lower")))
        upper.append(float(lim.get("upper")))
        vel.append(float(lim.get("velocity", "inf")))
    return lower, upper, vel


def _z_to(axis: Tensor) -> Tensor:
    """A rotation ``(3, 3)`` mapping the z axis onto the unit vector ``axis`` (float64)."""
    a = axis / axis.norm()
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    v, c = torch.linalg.cross(z, a), float(z @ a)
    if v.norm() < 1e-12:
        return (
            torch.eye(3, dtype=torch.float64)
            if c > 0
            else torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
        )
    vx = torch.tensor([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + vx + vx @ vx / (1 + c)


def _snap(x: float) -> float:
    for target in (0.0, 1.0, -1.0):
        if abs(x - target) < _SNAP:
            return target
    return x


class ArmKinematics(nn.Module):
    """A serial arm from a URDF: batched forward kinematics (module docstring).

    Args:
        urdf: a URDF path or its XML text; default the default robot's
            (:func:`protorch.robots.load_robot`: the Panda shipped with protorch).
        end_link: the chain's last link (default the default robot's end link).
        root_link: its first link (default the URDF's root).
        dtype, device: of the chain and the limits.

    Raises ``ValueError`` naming the problem for a URDF without ``end_link`` (or ``root_link``),
    a chain with other than revolute and fixed joints, or a joint without limits.
    """

    def __init__(
        self,
        urdf: str | Path | None = None,
        *,
        end_link: str | None = None,
        root_link: str = "",
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        import pytorch_kinematics as pk

        if urdf is None or end_link is None:
            default_urdf, default_end = default_chain()
            urdf, end_link = (
                default_urdf if urdf is None else urdf,
                default_end if end_link is None else end_link,
            )
        text, where = read_urdf(urdf)
        links = urdf_links(text, where)
        for role, name in (("end_link", end_link), ("root_link", root_link)):
            if name and name not in links:
                raise ValueError(
                    f"{where} has no link named {name!r} ({role}); its links are {links}"
                )
        try:
            chain = pk.build_serial_chain_from_urdf(text, end_link, root_link)
        except Exception as exc:  # the parser's own error types (ParseError, KeyError, ...)
            raise ValueError(f"{where} could not be read by pytorch_kinematics: {exc}") from exc
        frames = chain._serial_frames  # root .. end link (SerialChain keeps no public list of them)
        kinds = {f.joint.joint_type for f in frames[1:]}
        if not kinds <= {"revolute", "fixed"}:
            raise ValueError(
                f"only revolute and fixed joints are supported, {where} has {sorted(kinds)}"
            )
        self.urdf_source, self.urdf_text = where, text
        self.end_link, self.root_link = end_link, root_link or frames[0].name
        self.frame_names: list[str] = [f.name for f in frames]
        self.joint_names: list[str] = chain.get_joint_parameter_names()
        if not self.joint_names:
            raise ValueError(
                f"the chain {self.root_link} -> {end_link} of {where} has no movable joint"
            )
        self._frame_idx = [chain.frame_to_idx[n] for n in self.frame_names]
        lower, upper, vel = _joint_limits_from_xml(text, self.joint_names)
        kw = dict(dtype=dtype, device=device)
        self.register_buffer("lower", torch.tensor(lower, **kw))  # (J,)
        self.register_buffer("upper", torch.tensor(upper, **kw))  # (J,)
        self.register_buffer("max_velocity", torch.tensor(vel, **kw))  # (J,)
        self.chain = chain.to(dtype=dtype, device=device)
        self._compile(frames)

    # ------------------------------------------------------------------ sizes
    @property
    def num_joints(self) -> int:
        """``J``, the number of revolute joints of the chain."""
        return len(self.joint_names)

    @property
    def num_frames(self) -> int:
        """``F``, frames from the root to the end link (fixed ones included)."""
        return len(self.frame_names)

    def extra_repr(self) -> str:
        return (
            f"{self.root_link} -> {self.end_link}, joints={self.num_joints}, "
            f"frames={self.num_frames}"
        )

    def _apply(self, fn, *args, **kwargs):
        super()._apply(fn, *args, **kwargs)
        self.chain = self.chain.to(dtype=self.lower.dtype, device=self.lower.device)
        return self

    # ---------------------------------------------------------------- checks
    def check_joints(self, q, name: str = "q", *, finite: bool = True) -> Tensor:
        """``q (..., J)`` as a floating tensor; a clear error otherwise (``finite=False`` skips
        the pass over the values for NaN)."""
        if finite or not isinstance(q, Tensor):
            q = check_tensor(q, name, ndim_min=1)
        elif q.ndim < 1:
            raise ValueError(f"{name} must have at least 1 dimensions, got shape {tuple(q.shape)}")
        if q.shape[-1] != self.num_joints:
            raise ValueError(
                f"{name} must be (..., {self.num_joints}) joint values for the {self.num_joints} "
                "joints "
                f"{self.joint_names}, got shape {tuple(q.shape)}"
            )
        if not q.is_floating_point():
            q = q.to(self.lower.dtype)
        return q

    def _on_device(self, q: Tensor) -> Tensor:
        if q.device != self.lower.device:
            raise ValueError(
                f"q is on {q.device} but the chain is on {self.lower.device}: move one with .to()"
            )
        return q

    def within_limits(self, q: Tensor, tol: float = 0.0) -> Tensor:
        """Whether every joint of ``q (..., J)`` is inside ``[lower - tol, upper + tol]``:
        ``(...)``."""
        q = self.check_joints(q)
        lo, hi = self.lower.to(q), self.upper.to(q)
        return ((q >= lo - tol) & (q <= hi + tol)).all(-1)

    # ------------------------------------------------------------ kinematics
    def frames(self, q: Tensor) -> Tensor:
        """All frames, root to end link: ``q (..., J) -> (..., F, 4, 4)`` (one batched
        ``pytorch_kinematics`` call)."""
        q = self._on_device(self.check_joints(q))
        flat = q.reshape(-1, self.num_joints).to(self.lower.dtype)  # (P, J)
        mats = self.chain.forward_kinematics_tensor(flat)  # (F_chain, P, 4, 4)
        mats = mats[self._frame_idx].transpose(0, 1)  # (P, F, 4, 4)
        return mats.reshape(*q.shape[:-1], self.num_frames, 4, 4).to(q.dtype)

    def link_positions(self, q: Tensor) -> Tensor:
        """Origins of all frames, the arm's skeleton: ``(..., J) -> (..., F, 3)``."""
        return self.frames(q)[..., :3, 3]

    def ee_pose(self, q: Tensor) -> Tensor:
        """The end link's pose ``(..., 4, 4)``."""
        return self.frames(q)[..., -1, :, :]

    def jacobian(self, q: Tensor) -> Tensor:
        """Geometric Jacobian of the end link in the root frame: ``(..., J) -> (..., 6, J)``
        (rows: linear, then angular velocity)."""
        q = self._on_device(self.check_joints(q))
        flat = q.reshape(-1, self.num_joints).to(self.lower.dtype)  # (P, J)
        jac = self.chain.jacobian(flat)  # (P, 6, J)
        return jac.reshape(*q.shape[:-1], 6, self.num_joints).to(q.dtype)

    def ee_position(self, q: Tensor) -> Tensor:
        """The end link's origin, compiled path (module docstring): ``(..., J) -> (..., 3)``.
        Any floating dtype (float32 for sampling), any device. The hot path of the cost
        evaluation: the shape is checked, the values are not (NaN in gives NaN out)."""
        q = self.check_joints(q, finite=False)
        c, s = self.trig_rows(q)  # (J, P)
        x, y, z = (torch.full_like(c[0], v) for v in self._tail)
        for j in range(self.num_joints - 1, -1, -1):
            x, y = c[j] * x - s[j] * y, s[j] * x + c[j] * y  # rotation about the folded z axis
            x, y, z = self._affine(j, x, y, z)
        return torch.stack([x, y, z], -1).reshape(*q.shape[:-1], 3)

    def ee_frame(self, q: Tensor) -> Tensor:
        """The end link's pose by the compiled path: ``(..., J) -> (..., 4, 4)``, equal to the last
        of
        :meth:`frames` to round-off (its axes carried as :meth:`ee_position` carries its origin)."""
        q = self.check_joints(q, finite=False)
        x, y, z = self.ee_frame_rows(q)  # (4, P) each
        out = torch.zeros(*q.shape[:-1], 4, 4, dtype=q.dtype, device=q.device)
        out[..., :3, :] = torch.stack([x, y, z], 0).permute(2, 0, 1).reshape(*q.shape[:-1], 3, 4)
        out[..., 3, 3] = 1.0
        return out

    def ee_frame_rows(
        self, q: Tensor, trig: tuple[Tensor, Tensor] | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """:meth:`ee_frame`'s top three rows, component-major over the flattened batch ``P``:
        ``x, y, z (4, P)``, whose columns are the end link's x, y and z axes and its origin (no
        copies:
        what a caller placing points on the end link wants). ``trig``: :meth:`trig_rows` of
        ``q``, if known."""
        q = self.check_joints(q, finite=False)
        c, s = self.trig_rows(q) if trig is None else trig  # (J, P)
        tail = torch.tensor(
            self._maps[-1], dtype=q.dtype, device=q.device
        )  # (3, 4) end link in the last joint's frame
        vec = tail.T[:, :, None].expand(
            4, 3, c.shape[1]
        )  # (4, 3, P): the three axes, then the origin
        x, y, z = vec[:, 0], vec[:, 1], vec[:, 2]  # (4, P)
        origin = torch.tensor(
            [[0.0], [0.0], [0.0], [1.0]], dtype=q.dtype, device=q.device
        )  # translate the origin only
        for j in range(self.num_joints - 1, -1, -1):
            x, y = c[j] * x - s[j] * y, s[j] * x + c[j] * y
            x, y, z = self._affine(j, x, y, z, translate=origin)
        return x, y, z

    def skeleton(self, q: Tensor) -> Tensor:
        """The origins of all frames, root to end link, by the compiled path: ``(..., J) ->
        (..., F, 3)``, equal to :meth:`link_positions` to round-off at a fraction of its cost
        (:meth:`carry_points` of the frames' origins). Any floating dtype; the shape is checked,
        the values are not."""
        q = self.check_joints(q, finite=False)
        pts = torch.tensor(
            self._origins, dtype=q.dtype, device=q.device
        )  # (F, 3): each origin after its joint's rotation
        return self._stack_rows(q, *self._carry_rows(q, pts, self._after_joint))

    def point_plan(self, frames: Sequence[str], points: Tensor) -> PointPlan:
        """What :meth:`carry_points` needs to place ``points (M, 3)``, each fixed in its frame
        ``frames[m]`` (any order): each point in the frame after the last joint before its frame
        (float64), the points ordered by that joint, and per joint the first point after it."""
        points = check_tensor(points, "points", ndim=2).to(torch.float64).cpu()
        if points.shape != (len(frames), 3):
            raise ValueError(
                f"points must be ({len(frames)}, 3), one per frame, got {tuple(points.shape)}"
            )
        for f in frames:
            if f not in self._frame_maps:
                raise ValueError(f"the chain has no frame {f!r}; its frames are {self.frame_names}")
        joints = [self._frame_maps[f][0] for f in frames]
        order = sorted(
            range(len(frames)), key=lambda m: joints[m]
        )  # stable: by the joints before each point
        fixed = torch.tensor(
            [self._frame_maps[frames[m]][1] for m in order], dtype=torch.float64
        )  # (M, 3, 4)
        start = (fixed[:, :, :3] @ points[order][:, :, None])[..., 0] + fixed[:, :, 3]  # (M, 3)
        after = [bisect.bisect_right([joints[m] for m in order], k) for k in range(self.num_joints)]
        back = None if order == list(range(len(frames))) else torch.tensor(order).argsort()
        return PointPlan(start, after, back)

    def carry_points(self, q: Tensor, plan: PointPlan, *, functional: bool = False) -> Tensor:
        """The points of ``plan`` (:meth:`point_plan`) at joints ``q (..., J)``: ``(..., M, 3)`` in
        the root frame, in the plan's order of points, by the compiled path: every point carried
        back through the joints before its frame only, all points at once (ordered by frame, the
        points after joint ``k`` are a suffix: one slice per joint). Any floating dtype; the shape
        is checked, the values are not. ``functional``: the suffixes joined by ``torch.cat``
        instead of written into slices (the same numbers to the bit; what AOTInductor needs to
        compile an exported program, it refuses a slice of a constant written in place)."""
        q = self.check_joints(q, finite=False)
        return self._stack_rows(q, *self.carry_points_rows(q, plan, functional=functional))

    def carry_points_rows(
        self,
        q: Tensor,
        plan: PointPlan,
        *,
        functional: bool = False,
        trig: tuple[Tensor, Tensor] | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """:meth:`carry_points` component-major over the flattened batch: ``x, y, z (M, P)``
        (``trig``: ee_frame_rows')."""
        q = self.check_joints(q, finite=False)
        x, y, z = self._carry_rows(q, plan.start.to(q), plan.after, functional, trig)
        if plan.back is None:
            return x, y, z
        back = plan.back.to(q.device)
        return x.index_select(0, back), y.index_select(0, back), z.index_select(0, back)

    @staticmethod
    def _stack_rows(q: Tensor, x: Tensor, y: Tensor, z: Tensor) -> Tensor:
        """Component rows ``x, y, z (M, P)`` over ``q (..., J)``'s flattened batch as points
        ``(..., M, 3)``."""
        return torch.stack([x, y, z], -1).transpose(0, 1).reshape(*q.shape[:-1], x.shape[0], 3)

    def trig_rows(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``cos``, ``sin`` of ``q (..., J)`` as rows ``(J, P)``, each contiguous (a strided row
        costs ~3x per product)."""
        qt = q.reshape(-1, self.num_joints).T.contiguous()  # (J, P)
        return torch.cos(qt), torch.sin(qt)

    def _carry_rows(
        self,
        q: Tensor,
        pts: Tensor,
        after: Sequence[int],
        functional: bool = False,
        trig: tuple[Tensor, Tensor] | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Points ``pts (M, 3)``, each in the frame after its last joint's rotation and ordered by
        that joint (``after[k]``: the first point after joint ``k``), at ``q (..., J)``: their rows
        ``x, y, z (M, P)``. ``functional``: no tensor written in place (:meth:`carry_points`)."""
        c, s = self.trig_rows(q) if trig is None else trig  # (J, P)
        x, y, z = (pts[:, i, None].expand(-1, c.shape[1]) for i in range(3))  # (M, P)
        if not functional and any(0 < lo < pts.shape[0] for lo in after):  # rows written into below
            x, y, z = x.clone(), y.clone(), z.clone()
        for k, lo in reversed(list(enumerate(after))):  # lo: the first point after joint k
            if lo >= pts.shape[0]:
                continue
            xs, ys = c[k] * x[lo:] - s[k] * y[lo:], s[k] * x[lo:] + c[k] * y[lo:]  # (M - lo, P)
            xs, ys, zs = self._affine(k, xs, ys, z[lo:])
            if lo == 0:  # every point moves: the new rows replace the old (no copy)
                x, y, z = xs, ys, zs
            elif functional:
                x, y, z = (torch.cat([v[:lo], w]) for v, w in ((x, xs), (y, ys), (z, zs)))
            else:
                x[lo:], y[lo:], z[lo:] = xs, ys, zs
        return (
            x.contiguous(),
            y.contiguous(),
            z.contiguous(),
        )  # (a row no joint moved would be a view of pts)

    def jacobian_pose(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """The end link's geometric Jacobian and pose by the compiled chain: ``q (B, J) -> (B, 6,
        J),
        (B, 4, 4)``, equal to :meth:`jacobian` and the last of :meth:`frames` to round-off at a
        fraction of ``pytorch_kinematics``' cost for small batches: the frames are accumulated
        forward, ``F_{k+1} = F_k Rz(q_k) G_k``, joint ``k`` turning about ``F_k``'s z axis through
        its origin (column ``k``: ``z_k x (p - o_k)`` over ``z_k``)."""
        q = self._on_device(self.check_joints(q))
        maps = torch.tensor(self._maps, dtype=q.dtype, device=q.device)  # (J+1, 3, 4)
        frame = maps[0].expand(q.shape[0], 3, 4)  # (B, 3, 4) F_0
        c, s = torch.cos(q)[:, None], torch.sin(q)[:, None]  # (B, 1, J)
        axes, origins = [], []
        for k in range(self.num_joints):
            axes.append(frame[:, :, 2])
            origins.append(frame[:, :, 3])
            x, y = frame[:, :, 0], frame[:, :, 1]  # (B, 3)
            rot = torch.stack(
                [c[:, :, k] * x + s[:, :, k] * y, c[:, :, k] * y - s[:, :, k] * x, frame[:, :, 2]],
                -1,
            )
            frame = torch.cat(
                [rot @ maps[k + 1][:, :3], (rot @ maps[k + 1][:, 3:]) + frame[:, :, 3:]], -1
            )
        z, o = torch.stack(axes, -1), torch.stack(origins, -1)  # (B, 3, J)
        lin = torch.linalg.cross(z, frame[:, :, 3:] - o, dim=1)  # (B, 3, J)
        pose = torch.cat(
            [
                frame,
                torch.tensor([[[0.0, 0.0, 0.0, 1.0]]], dtype=q.dtype, device=q.device).expand(
                    q.shape[0], 1, 4
                ),
            ],
            1,
        )  # (B, 4, 4)
        return torch.cat([lin, z], 1), pose

    # ------------------------------------------------------------------- IK
    def inverse(self, position: Tensor, q0: Tensor, **options) -> tuple[Tensor, Tensor]:
        """Damped-least-squares inverse kinematics of the end link, batched:
        :func:`protorch.robots.ik.inverse_kinematics` (its options: ``rotation``, ``rest``,
        ``iters``, ``damping``, ``rotation_weight``, ``null_gain``, ``max_step``, ``tol``,
        ``compiled``).
        Returns ``(q (B, J), position error (B,))``."""
        return inverse_kinematics(self, position, q0, **options)

    # ---------------------------------------------------------------- compile
    def _compile(self, frames) -> None:
        """Fold the chain into ``G_0 Rz(q_1) G_1 ... Rz(q_J) G_J`` (fixed affine maps ``G``)."""
        eye = torch.eye(4, dtype=torch.float64)

        def mat(t):
            return eye.clone() if t is None else t.get_matrix()[0].to(torch.float64)

        maps: list[Tensor] = []
        acc = eye.clone()  # the fixed map accumulated since the last revolute joint
        self._frame_maps = {
            frames[0].name: (0, eye[:3].tolist())
        }  # frame -> (joints before it, its fixed map)
        for f in frames[1:]:
            static = mat(f.link.offset) @ mat(f.joint.offset)  # as pytorch_kinematics composes them
            acc = acc @ static
            if f.joint.joint_type == "revolute":
                a = torch.eye(4, dtype=torch.float64)
                a[:3, :3] = _z_to(f.joint.axis.to(torch.float64))
                maps.append(acc @ a)  # ... then Rz(q) about the folded axis
                acc = a.T.clone()  # A^T: back to the joint's own frame
            self._frame_maps[f.name] = (len(maps), acc[:3].tolist())
        maps.append(acc)  # the tail: from the last joint to the end link
        # for skeleton(): every frame's origin in the frame after its last joint, and per joint the
        # first
        # frame after it (a serial chain's frames come after non-decreasing numbers of joints)
        joints = [self._frame_maps[f.name][0] for f in frames]
        self._origins = [[row[3] for row in self._frame_maps[f.name][1]] for f in frames]
        self._after_joint = [joints.index(k + 1) for k in range(len(maps) - 1)]
        self._maps = [[[_snap(float(v)) for v in row] for row in m[:3].tolist()] for m in maps]
        self._tail = [
            self._maps[-1][r][3] for r in range(3)
        ]  # the end point in the last joint's frame

    def _affine(
        self, j: int, x: Tensor, y: Tensor, z: Tensor, translate: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Apply the fixed map ``G_j`` (before joint ``j``'s rotation) to the point ``(x, y, z)``,
        skipping zero terms and multiplications by +-1; ``translate`` (broadcasting to ``x``)
        weighs the translation (1: a point, 0: a direction)."""
        out = []
        for row in self._maps[j]:
            acc = None
            for coef, v in zip(row[:3], (x, y, z)):
                if coef == 0.0:
                    continue
                term = v if coef == 1.0 else (-v if coef == -1.0 else coef * v)
                acc = term if acc is None else acc + term
            if acc is None:
                acc = torch.zeros_like(x)
            if row[3] != 0.0:
                acc = acc + (row[3] if translate is None else row[3] * translate)
            out.append(acc)
        return out[0], out[1], out[2]
