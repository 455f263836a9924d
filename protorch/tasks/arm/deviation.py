"""Deviation of an end-effector path from the straight path, the ``d`` of the arm's objectives.

The paper's ``d`` is the mean distance to the straight path ``tau_direct(t)``; two readings:

* ``"segment"``: the distance of each point to the *segment* ``s -> g`` (time ignored: a path
  that lingers or hurries along the line costs nothing);
* ``"time"``: the distance of ``p(t)`` to the straight path at the same instant,
  ``tau_direct(t) = s + t / (T - 1) (g - s)`` over the path's ``T`` evenly spaced samples (the
  line travelled at constant speed).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["DEVIATIONS", "segment_deviation", "time_aligned_deviation", "deviation"]

DEVIATIONS = ("segment", "time")


def segment_deviation(p: Tensor, s: Tensor, g: Tensor) -> Tensor:
    """Distance of points ``p (..., T, 3)`` to the segments ``s -> g`` (``(..., 3)``): ``(...,
    T)``."""
    d = (g - s)[..., None, :]  # (..., 1, 3)
    u = ((p - s[..., None, :]) * d).sum(-1) / d.square().sum(-1).clamp_min(1e-12)  # (..., T)
    return (p - s[..., None, :] - u.clamp(0, 1)[..., None] * d).norm(dim=-1)


def time_aligned_deviation(p: Tensor, s: Tensor, g: Tensor) -> Tensor:
    """Distance of ``p (..., T, 3)`` to ``tau_direct(t)`` at the same instant: ``(..., T)``."""
    t = torch.linspace(0, 1, p.shape[-2], dtype=p.dtype, device=p.device)[:, None]  # (T, 1)
    direct = s[..., None, :] + t * (g - s)[..., None, :]  # (..., T, 3)
    return (p - direct).norm(dim=-1)


def deviation(kind: str, p: Tensor, s: Tensor, g: Tensor) -> Tensor:
    """``kind`` in :data:`DEVIATIONS`: ``(..., T)`` distances."""
    if kind == "segment":
        return segment_deviation(p, s, g)
    if kind == "time":
        return time_aligned_deviation(p, s, g)
    raise ValueError(f"deviation must be one of {list(DEVIATIONS)}, got {kind!r}")
