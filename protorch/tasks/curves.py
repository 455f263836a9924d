"""Smooth curves shared by the synthetic demonstrators (point particle, beam operator).

Both functions are batched over ``n`` curves and work in any dimension ``D``.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["catmull_rom", "smooth_noise"]


def catmull_rom(via: Tensor, s: Tensor) -> Tensor:
    """Cubic Hermite curves through ``via (n, P, D)`` with Catmull-Rom tangents on a chord-length
    parameter, evaluated at ``s (n, T)`` in ``[0, 1]``: ``(n, T, D)``.

    The curve passes through every via point (at the chord-length knot of each); the end
    tangents are the end chords (reflected ghost points)."""
    dim = via.shape[-1]
    chord = (via[:, 1:] - via[:, :-1]).norm(dim=-1).clamp_min(1e-9)  # (n, P-1)
    knots = torch.cat([chord.new_zeros(len(via), 1), chord.cumsum(-1)], -1)  # (n, P)
    knots = knots / knots[:, -1:]  # (n, P)
    # reflected ghost points at both ends, so the end tangents are the end chords
    pad = torch.cat(
        [2 * via[:, :1] - via[:, 1:2], via, 2 * via[:, -1:] - via[:, -2:-1]], 1
    )  # (n, P+2, D)
    kpad = torch.cat(
        [2 * knots[:, :1] - knots[:, 1:2], knots, 2 * knots[:, -1:] - knots[:, -2:-1]], 1
    )  # (n, P+2)
    tangent = (pad[:, 2:] - pad[:, :-2]) / (kpad[:, 2:] - kpad[:, :-2])[
        ..., None
    ]  # (n, P, D) d via / d s
    s = s.clamp(0, 1).contiguous()  # (n, T)
    i = (
        torch.searchsorted(knots.contiguous(), s, right=True).clamp(1, via.shape[1] - 1) - 1
    )  # (n, T)
    k0, k1 = knots.gather(1, i), knots.gather(1, i + 1)  # (n, T)
    h = (k1 - k0)[..., None]  # (n, T, 1)
    x = ((s - k0)[..., None] / h).clamp(0, 1)  # (n, T, 1)
    idx = i[..., None].expand(*i.shape, dim)  # (n, T, D)
    p0, p1 = via.gather(1, idx), via.gather(1, idx + 1)  # (n, T, D)
    m0, m1 = tangent.gather(1, idx), tangent.gather(1, idx + 1)  # (n, T, D)
    h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x  # (n, T, 1)
    h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2  # (n, T, 1)
    return h00 * p0 + h10 * h * m0 + h01 * p1 + h11 * h * m1  # (n, T, D)


def smooth_noise(
    u: Tensor, scale: float, generator: torch.Generator | None, *, dim: int = 2, knots: int = 8
) -> Tensor:
    """Low-frequency ``dim``-D noise of std about ``scale`` at times ``u (n, T)`` in ``[0, 1]``: a
    smooth (raised-cosine) blend of ``knots`` random knots per row, ``(n, T, dim)``. More knots
    give faster wiggles (``knots - 1`` blends per curve)."""
    if int(knots) < 2:
        raise ValueError(f"knots must be >= 2, got {knots}")
    k = int(knots)
    values = scale * torch.randn(
        u.shape[0], k, dim, generator=generator, dtype=u.dtype
    )  # (n, k, dim)
    pos = (k - 1) * u  # (n, T)
    lo = pos.floor().long().clamp(0, k - 2)  # (n, T)
    w = (0.5 - 0.5 * torch.cos(torch.pi * (pos - lo)))[..., None]  # (n, T, 1) smooth blend
    idx = lo[..., None].expand(*lo.shape, dim)  # (n, T, dim)
    return values.gather(1, idx) * (1 - w) + values.gather(1, idx + 1) * w  # (n, T, dim)
