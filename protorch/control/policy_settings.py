"""Moved to :mod:`protorch.policy.settings` (this name kept for old imports)."""

from ..policy.settings import moving_test_defaults, policy_settings

__all__ = ["moving_test_defaults", "policy_settings"]
