"""Moved to :mod:`protorch.policy.policy` (this name kept for old imports)."""

from ..policy.means import ClassMeans
from ..policy.policy import DEFAULT_BLEND, Policy, Reference

__all__ = ["DEFAULT_BLEND", "ClassMeans", "Policy", "Reference"]
