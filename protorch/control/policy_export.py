"""Moved to :mod:`protorch.policy.export` (this name kept for old imports)."""

from ..policy.export import ExportProgram, static_gaps, write_program

__all__ = ["ExportProgram", "static_gaps", "write_program"]
