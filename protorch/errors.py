"""The base of every error protorch raises on purpose.

``except ProtorchError`` catches any of them; each also keeps the builtin base it had, so
``except ValueError`` (or ``TypeError``, ``ImportError``) still works:

- :class:`protorch.tasks.base.TaskContractError` (``TypeError``, ``ValueError``): a task object
  that does not meet the task protocol;
- :class:`protorch.sim.mj.MujocoMissing` (``ImportError``): the ``physics`` extra is not installed;
- :class:`protorch.experiments.settings.SettingsError` (``ValueError``): an experiment setting
  out of range or of the wrong type;
- :class:`protorch.data.files.CheckpointError` (``ValueError``): a checkpoint that is missing,
  truncated or from an incompatible run;
- :class:`protorch.robots.clean.CleanError` (``ValueError``): a URDF the cleaner cannot use;
- :class:`protorch.data.cleaning.TooShort` (``ValueError``): a recording too short after trimming;
- :class:`protorch.robots.loader.RobotError` (``ValueError``): a robot description that cannot be
  used (a URDF that does not parse, a missing end link, a home pose of the wrong length, ...).

>>> from protorch.errors import ProtorchError
>>> from protorch.data.files import CheckpointError
>>> issubclass(CheckpointError, ProtorchError) and issubclass(CheckpointError, ValueError)
True
"""

from __future__ import annotations

__all__ = ["ProtorchError"]


class ProtorchError(Exception):
    """Base class of protorch's own exceptions (each subclass also keeps its builtin base)."""
