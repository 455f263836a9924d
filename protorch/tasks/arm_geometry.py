"""Geometry of the arm-reach task (:class:`~protorch.tasks.ArmReachTask`): the homotopy
classes, the hand's start orientation and the exact distances of a segment to the can's axis
segment and of points to a segment."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["LEFT", "RIGHT", "SIDES", "down_rotation", "point_segment_distance", "segment_axis_distance"]

LEFT, RIGHT = 0, 1
SIDES = {LEFT: "left", RIGHT: "right"}


def down_rotation(dtype=torch.float64, device=None) -> Tensor:
    """The hand's orientation at the start: tool ``z`` down, tool ``x`` along ``+x``: ``(3, 3)``."""
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], dtype=dtype, device=device)


def segment_axis_distance(a: Tensor, b: Tensor, axis_xy: Tensor, z0: float, z1: float) -> Tensor:
    """Exact distance between the segments ``a -> b`` (``(..., 3)``) and the vertical axis segment
    ``{(axis_x, axis_y, z): z0 <= z <= z1}`` (``axis_xy (..., 2)``): ``(...)``.

    Along the segment ``p(u) = a + u (b - a)`` the squared distance is
    ``h(u)^2 + v(u)^2`` with ``h`` the horizontal distance and ``v = max(0, z(u) - z1, z0 - z(u))``,
    a convex piecewise quadratic; its minimum over ``[0, 1]`` is at an end, a breakpoint
    (``z(u) = z0`` or ``z1``) or a stationary point of a piece, so evaluating it at those seven
    candidates is exact.
    """
    shape = torch.broadcast_shapes(a.shape[:-1], b.shape[:-1], axis_xy.shape[:-1])
    a, b = a.expand(*shape, 3), b.expand(*shape, 3)
    P = a[..., :2] - axis_xy  # (..., 2)
    Q = b[..., :2] - a[..., :2]  # (..., 2)
    za, dz = a[..., 2], b[..., 2] - a[..., 2]  # (...)
    pq, qq = (P * Q).sum(-1), (Q * Q).sum(-1)  # (...)
    tiny = torch.finfo(a.dtype).tiny

    def ratio(num, den):
        return torch.where(den > tiny, num / den.clamp_min(tiny), torch.zeros_like(num))

    cands = [
        torch.zeros_like(za), torch.ones_like(za), ratio(-pq, qq),
        ratio(-(pq + dz * (za - z1)), qq + dz * dz), ratio(-(pq + dz * (za - z0)), qq + dz * dz),
        ratio(z0 - za, dz), ratio(z1 - za, dz),
    ]
    u = torch.stack(cands, -1).clamp(0.0, 1.0)  # (..., 7)
    h = P[..., None, :] + u[..., None] * Q[..., None, :]  # (..., 7, 2)
    z = za[..., None] + u * dz[..., None]  # (..., 7)
    v = torch.clamp(torch.maximum(z - z1, z0 - z), min=0.0)  # (..., 7)
    return (h.square().sum(-1) + v.square()).amin(-1).sqrt()  # (...)


def point_segment_distance(p: Tensor, s: Tensor, g: Tensor) -> Tensor:
    """Distance of points ``p (..., T, 3)`` to the segments ``s -> g`` (``(..., 3)``): ``(..., T)``."""
    d = (g - s)[..., None, :]  # (..., 1, 3)
    u = ((p - s[..., None, :]) * d).sum(-1) / d.square().sum(-1).clamp_min(1e-12)  # (..., T)
    return (p - s[..., None, :] - u.clamp(0, 1)[..., None] * d).norm(dim=-1)
