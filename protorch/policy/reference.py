"""What :meth:`~protorch.policy.policy.Policy.reference` returns (:class:`Reference`), the state
of one motion (:class:`MotionState`) and the input check without torch (:func:`as_array`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from torch import Tensor

__all__ = ["MotionState", "Reference", "as_array"]


def as_array(x, shape: tuple, name: str):
    """``x`` as a float64 NumPy array of its own of ``shape`` (``None`` stays ``None``); one
    ``ValueError`` naming ``name`` for a wrong shape or a NaN or inf."""
    if x is None:
        return None
    if isinstance(x, Tensor):
        x = x.numpy(force=True)
    a = np.array(x, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"{name} must be {shape} values, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} holds NaN or inf: {a.tolist()}")
    return a


class _Reference(NamedTuple):
    q: Tensor  # (D,) reference position
    qd: Tensor  # (D,) velocity
    qdd: Tensor  # (D,) acceleration
    label: int  # the class tracked (0 for a map with one class)


class Reference(_Reference):
    """What :meth:`Policy.reference` returns: the tuple ``(q, qd, qdd (D,), label)`` (float64; the
    ProMP's device inline, the CPU with ``planner="thread"``) and the attribute ``plan_t``, the time
    ``t`` of the inputs the plan in use was made from (inline: the call's own ``t``)."""

    def __new__(cls, q, qd, qdd, label, plan_t: float = math.nan):
        self = tuple.__new__(cls, (q, qd, qdd, label))  # the named tuple's own __new__, inlined
        self.plan_t = plan_t
        return self


class MotionState:
    """The state of one motion (:meth:`Policy.reset` starts a new one), kept apart from the
    module's attributes so that writing it at every call is cheap."""

    __slots__ = ("current", "fresh", "off", "slot", "t", "turn", "w")

    def __init__(self) -> None:
        self.current: int | None = None  # row of Policy.labels
        self.slot = -1  # the decision slot of the last decision
        self.w: Tensor | None = None  # (1, N) the weights tracked at the last call
        self.t = 0.0
        self.off: Tensor | None = None  # (2, D) offset and its velocity at t
        self.fresh = 0.0  # when the other classes' neighbour sets were last brought up to date
        self.turn = 0  # the other class to bring up to date next
