"""Geometry of the arm-reach task (:class:`~protorch.tasks.ArmReachTask`): the homotopy
classes, the hand's start orientation and the exact distances of a segment to the can's axis
segment, of a segment to the can's solid cylinder, and of points to a segment."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "LEFT",
    "RIGHT",
    "SIDES",
    "broadcast_shape",
    "down_rotation",
    "point_segment_distance",
    "segment_axis_distance",
    "segment_axis_closest",
    "point_cylinder_distance",
    "segment_cylinder_distance",
    "segment_cylinder_within",
]

_GOLDEN = (5**0.5 - 1) / 2  # 0.618...

LEFT, RIGHT = 0, 1
SIDES = {LEFT: "left", RIGHT: "right"}


def broadcast_shape(*shapes) -> torch.Size:
    """``torch.broadcast_shapes`` computed by numpy's: the same shape (a ``ValueError`` where they
    do not broadcast) in about 2 us instead of 26 (torch's is written in Python; a class
    decision's plan check asks three times)."""
    return torch.Size(np.broadcast_shapes(*shapes))


def down_rotation(dtype=torch.float64, device=None) -> Tensor:
    """The hand's orientation at the start: tool ``z`` down, tool ``x`` along ``+x``: ``(3, 3)``."""
    return torch.tensor(
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], dtype=dtype, device=device
    )


def _axis_candidates(
    a: Tensor, b: Tensor, axis_xy: Tensor, z0: float, z1: float
) -> tuple[Tensor, Tensor]:
    """:func:`segment_axis_distance`'s seven candidate parameters ``u (..., 7)`` and the squared
    distances there ``(..., 7)``."""
    shape = broadcast_shape(a.shape[:-1], b.shape[:-1], axis_xy.shape[:-1])
    a, b = a.expand(*shape, 3), b.expand(*shape, 3)
    # component by component: the same numbers as sums over a last axis of 2, which torch reduces
    # slowly
    px, py = (
        a[..., 0] - axis_xy[..., 0],
        a[..., 1] - axis_xy[..., 1],
    )  # (...) a's horizontal offset from the axis
    qx, qy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]  # (...)
    za, dz = a[..., 2], b[..., 2] - a[..., 2]  # (...)
    pq, qq = px * qx + py * qy, qx * qx + qy * qy  # (...)
    tiny = torch.finfo(a.dtype).tiny

    def ratio(num, den):
        return torch.where(den > tiny, num / den.clamp_min(tiny), torch.zeros_like(num))

    cands = [
        torch.zeros_like(za),
        torch.ones_like(za),
        ratio(-pq, qq),
        ratio(-(pq + dz * (za - z1)), qq + dz * dz),
        ratio(-(pq + dz * (za - z0)), qq + dz * dz),
        ratio(z0 - za, dz),
        ratio(z1 - za, dz),
    ]
    u = torch.stack(cands, -1).clamp(0.0, 1.0)  # (..., 7)
    hx, hy = (
        px[..., None] + u * qx[..., None],
        py[..., None] + u * qy[..., None],
    )  # (..., 7) horizontal offsets
    z = za[..., None] + u * dz[..., None]  # (..., 7)
    v = torch.clamp(torch.maximum(z - z1, z0 - z), min=0.0)  # (..., 7)
    return u, (hx * hx + hy * hy) + v * v


def segment_axis_distance(a: Tensor, b: Tensor, axis_xy: Tensor, z0: float, z1: float) -> Tensor:
    """Exact distance between the segments ``a -> b`` (``(..., 3)``) and the vertical axis segment
    ``{(axis_x, axis_y, z): z0 <= z <= z1}`` (``axis_xy (..., 2)``): ``(...)``.

    Along the segment ``p(u) = a + u (b - a)`` the squared distance is
    ``h(u)^2 + v(u)^2`` with ``h`` the horizontal distance and ``v = max(0, z(u) - z1, z0 - z(u))``,
    a convex piecewise quadratic; its minimum over ``[0, 1]`` is at an end, a breakpoint
    (``z(u) = z0`` or ``z1``) or a stationary point of a piece, so evaluating it at those seven
    candidates is exact.
    """
    return _axis_candidates(a, b, axis_xy, z0, z1)[1].amin(-1).sqrt()  # (...)


def segment_axis_closest(
    a: Tensor, b: Tensor, axis_xy: Tensor, z0: float, z1: float
) -> tuple[Tensor, Tensor]:
    """:func:`segment_axis_distance` (the same numbers) and the segment's parameter ``u`` of a
    closest point: both ``(...)``."""
    u, d2 = _axis_candidates(a, b, axis_xy, z0, z1)  # (..., 7) each
    best, i = d2.min(-1)  # (...)
    return best.sqrt(), u.gather(-1, i[..., None])[..., 0]


def point_segment_distance(p: Tensor, s: Tensor, g: Tensor) -> Tensor:
    """Distance of points ``p (..., T, 3)`` to the segments ``s -> g`` (``(..., 3)``): ``(...,
    T)``."""
    d = (g - s)[..., None, :]  # (..., 1, 3)
    u = ((p - s[..., None, :]) * d).sum(-1) / d.square().sum(-1).clamp_min(1e-12)  # (..., T)
    return (p - s[..., None, :] - u.clamp(0, 1)[..., None] * d).norm(dim=-1)


def point_cylinder_distance(
    p: Tensor, axis_xy: Tensor, radius: float, z0: float, z1: float
) -> Tensor:
    """Signed distance of points ``p (..., 3)`` to the solid vertical cylinder of ``radius`` over
    ``axis_xy (..., 2)`` from ``z0`` to ``z1`` (negative inside): ``(...)``."""
    rho = (p[..., :2] - axis_xy).norm(dim=-1) - radius  # (...)
    v = torch.maximum(z0 - p[..., 2], p[..., 2] - z1)  # (...)
    outside = torch.sqrt(rho.clamp(min=0).square() + v.clamp(min=0).square())
    return torch.where((rho > 0) | (v > 0), outside, torch.maximum(rho, v))


def segment_cylinder_distance(
    a: Tensor, b: Tensor, axis_xy: Tensor, radius: float, z0: float, z1: float, iters: int = 40
) -> Tensor:
    """Smallest signed distance between the segments ``a -> b`` (``(..., 3)``) and the solid
    vertical cylinder of ``radius`` over ``axis_xy (..., 2)`` from ``z0`` to ``z1``: ``(...)``.

    A convex body's signed distance is convex along a segment, so a golden-section search over
    the segment's parameter finds the minimum: after ``iters`` steps the bracket is
    ``0.618^iters`` of the segment's length (``4e-9`` for 40), and the ends are evaluated too.
    """
    f, lo, hi = _along(a, b, axis_xy, radius, z0, z1)
    x1, x2 = hi - _GOLDEN, lo + _GOLDEN
    f1, f2 = f(x1), f(x2)
    for _ in range(int(iters)):
        lo, x1, f1, x2, f2, hi, _ = _golden_step(f, lo, x1, f1, x2, f2, hi)
    ends = torch.minimum(f(torch.zeros_like(lo)), f(torch.ones_like(lo)))
    return torch.minimum(torch.minimum(f1, f2), ends)


def _along(a: Tensor, b: Tensor, axis_xy: Tensor, radius: float, z0: float, z1: float):
    """The signed distance along the segments as a function of their parameter, and the bracket
    ``[0, 1]``."""
    shape = broadcast_shape(a.shape[:-1], b.shape[:-1], axis_xy.shape[:-1])
    a, b, axis_xy = a.expand(*shape, 3), b.expand(*shape, 3), axis_xy.expand(*shape, 2)
    d = b - a

    def f(u: Tensor) -> Tensor:
        return point_cylinder_distance(a + u[..., None] * d, axis_xy, radius, z0, z1)

    return (
        f,
        torch.zeros(shape, dtype=a.dtype, device=a.device),
        torch.ones(shape, dtype=a.dtype, device=a.device),
    )


def _golden_step(f, lo, x1, f1, x2, f2, hi):
    """One step of the golden-section search: the new bracket, its interior points and values,
    and whether the left part was kept (``left``: the minimum lies in ``[lo, x2]``)."""
    left = f1 < f2
    lo, hi = torch.where(left, lo, x1), torch.where(left, x2, hi)
    new = torch.where(left, hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo))
    fn = f(new)
    x1, x2 = torch.where(left, new, x2), torch.where(left, x1, new)
    f1, f2 = torch.where(left, fn, f2), torch.where(left, f1, fn)
    return lo, x1, f1, x2, f2, hi, left


def segment_cylinder_within(
    a: Tensor,
    b: Tensor,
    axis_xy: Tensor,
    radius: float,
    z0: float,
    z1: float,
    r: Tensor,
    margin: float | Tensor,
    iters: int = 40,
    every: int = 3,
) -> Tensor:
    """Whether ``segment_cylinder_distance(a, b, ...) - r <= margin``: ``(...)`` bool (``margin``
    one number or one per entry), the same
    verdict from the same golden-section steps, each entry stopped once it is decided: within as
    soon as a point evaluated is (the search's result is the smallest value it evaluated), clear
    as soon as a lower bound of the distance over the bracket exceeds ``margin + r`` (by 1e-12:
    round-off; the search's result is never below the true minimum). The bound is convexity's
    (the signed distance to a convex body is convex along a segment): outside the two interior
    points the line through them, between them the larger of the lines through each interior
    point and its bracket end. Checked every ``every`` steps; entries still open after ``iters``
    steps take the search's own result."""
    f, lo, hi = _along(a, b, axis_xy, radius, z0, z1)
    r = r.expand(lo.shape)
    f_lo, f_hi = f(lo), f(hi)  # the ends, which the full search evaluates last
    x1, x2 = hi - _GOLDEN, lo + _GOLDEN
    f1, f2 = f(x1), f(x2)
    best = torch.minimum(
        torch.minimum(f1, f2), torch.minimum(f_lo, f_hi)
    )  # the smallest value evaluated
    within = best - r <= margin
    open_ = ~within
    for i in range(int(iters)):
        if i and i % every == 0:
            open_ = open_ & ~(
                _convex_bound(lo, f_lo, x1, f1, x2, f2, hi, f_hi) - r > margin + 1e-12
            )
            if not bool(open_.any()):
                return within
        f1o, f2o = f1, f2
        lo, x1, f1, x2, f2, hi, left = _golden_step(f, lo, x1, f1, x2, f2, hi)
        f_lo, f_hi = torch.where(left, f_lo, f1o), torch.where(left, f2o, f_hi)
        best = torch.minimum(best, torch.minimum(f1, f2))
        hit = open_ & (best - r <= margin)
        within, open_ = within | hit, open_ & ~hit
    return within


def _convex_bound(lo, f_lo, x1, f1, x2, f2, hi, f_hi) -> Tensor:
    """A lower bound of a convex function over ``[lo, hi]`` from its values at ``lo < x1 < x2 <
    hi``: on ``[lo, x1]`` and ``[x2, hi]`` the line through the interior points (extended), on
    ``[x1, x2]`` the larger of the lines through ``lo, x1`` and through ``x2, hi`` (extended),
    smallest at ``x1``, ``x2`` or where they cross."""
    s = (f2 - f1) / (x2 - x1)
    outer = torch.minimum(
        torch.minimum(f1 - s * (x1 - lo), f1), torch.minimum(f2 + s * (hi - x2), f2)
    )
    s1, s2 = (f1 - f_lo) / (x1 - lo), (f_hi - f2) / (hi - x2)

    def g(x):
        return torch.maximum(f1 + s1 * (x - x1), f2 + s2 * (x - x2))

    cross = ((f2 - s2 * x2) - (f1 - s1 * x1)) / (s1 - s2)
    cross = torch.where(torch.isfinite(cross), cross, x1)
    inner = torch.minimum(
        torch.minimum(g(x1), g(x2)), g(torch.minimum(torch.maximum(cross, x1), x2))
    )
    return torch.minimum(outer, inner)
