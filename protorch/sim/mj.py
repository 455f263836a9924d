"""MuJoCo, imported on demand: the physics test is optional (``pip install "protorch[physics]"``).

Nothing in :mod:`protorch.sim` imports ``mujoco`` at module level, so the rest of protorch (and
``experiment=arm_reach`` without its physics section) works where MuJoCo is not installed;
:func:`load_mujoco` raises :class:`MujocoMissing`, one line naming the extra, where it is needed.
"""

from __future__ import annotations

import importlib

from ..errors import ProtorchError

__all__ = [
    "PHYSICS_EXTRA",
    "INSTALL_HINT",
    "MIN_VERSION",
    "MujocoMissing",
    "load_mujoco",
    "mujoco_available",
]

PHYSICS_EXTRA = "physics"
INSTALL_HINT = 'pip install "protorch[physics]"'
MIN_VERSION = (4, 0)  # mujoco.batch (many simulations stepped on a thread pool) is new in 4.0


class MujocoMissing(ProtorchError, ImportError):
    """MuJoCo (>= 4.0) is not installed; the message is one line naming the extra."""


def load_mujoco():
    """The ``mujoco`` module (with ``mujoco.batch`` imported), or :class:`MujocoMissing`."""
    try:
        mujoco = importlib.import_module("mujoco")
        importlib.import_module("mujoco.batch")
    except ImportError as exc:
        raise MujocoMissing(
            f"the physics test needs MuJoCo >= {'.'.join(map(str, MIN_VERSION))}: {INSTALL_HINT} "
            f"({exc})"
        ) from None
    return mujoco


def mujoco_available() -> bool:
    """Whether :func:`load_mujoco` would succeed."""
    try:
        load_mujoco()
    except MujocoMissing:
        return False
    return True
