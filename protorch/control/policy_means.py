"""Moved to :mod:`protorch.policy.means` (this name kept for old imports)."""

from ..policy.means import (
    MAX_RANK,
    MAX_SWAPS,
    MAX_UPDATES,
    SPARE,
    ClassMeans,
    EndEffector,
    basis3,
    decay_matrix,
)

__all__ = [
    "MAX_RANK",
    "MAX_SWAPS",
    "MAX_UPDATES",
    "SPARE",
    "ClassMeans",
    "EndEffector",
    "basis3",
    "decay_matrix",
]
