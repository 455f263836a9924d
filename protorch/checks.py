"""Input validation shared by the library: every public entry point checks its inputs here
before doing any work, so a bad call fails with an error that names the problem."""

from __future__ import annotations

import math
import numbers
from typing import Sequence

import torch
from torch import Tensor


def check_tensor(x, name: str, *, ndim_min: int | None = None, ndim: int | None = None) -> Tensor:
    """Return ``x`` as a tensor, raising if it is not finite or has the wrong rank."""
    if not isinstance(x, Tensor):
        try:
            x = torch.as_tensor(x)
        except Exception as exc:  # pragma: no cover - torch's own message is kept
            raise TypeError(
                f"{name} must be a tensor or array-like, got {type(x).__name__}"
            ) from exc
    if ndim is not None and x.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {tuple(x.shape)}")
    if ndim_min is not None and x.ndim < ndim_min:
        raise ValueError(
            f"{name} must have at least {ndim_min} dimensions, got shape {tuple(x.shape)}"
        )
    if x.is_floating_point() and not all_finite(x):
        bad = "NaN" if bool(torch.isnan(x).any()) else "inf"
        raise ValueError(f"{name} contains {bad} values")
    return x


def all_finite(x: Tensor) -> bool:
    """Whether every entry of the floating tensor ``x`` is finite (an empty one is).

    The smallest and the largest entry are finite exactly when every entry is (a NaN anywhere
    makes both NaN): ``aminmax`` reads the tensor once without allocating a mask."""
    if x.numel() == 0:
        return True
    # aminmax would copy a non-contiguous tensor first: two strided passes are cheaper
    lo, hi = torch.aminmax(x) if x.is_contiguous() else (x.amin(), x.amax())
    return math.isfinite(lo.item()) and math.isfinite(hi.item())


def check_positive(value, name: str) -> None:
    """Raise unless ``value`` (a number or a tensor) is finite and > 0 everywhere."""
    if isinstance(value, Tensor):
        ok = bool(torch.isfinite(value).all()) and bool((value > 0).all())
    else:
        ok = value is not None and math.isfinite(float(value)) and float(value) > 0
    if not ok:
        raise ValueError(f"{name} must be finite and > 0, got {value}")


def check_nonnegative(x: Tensor, name: str) -> None:
    if bool((x < 0).any()):
        raise ValueError(f"{name} must be >= 0, got a minimum of {float(x.min()):.3g}")


def check_last_dim(x: Tensor, size: int, name: str) -> None:
    if x.shape[-1] != size:
        raise ValueError(f"{name} must have last dimension {size}, got shape {tuple(x.shape)}")


def check_same_batch(shapes: Sequence[tuple], names: Sequence[str]) -> None:
    first = shapes[0]
    for shape, name in zip(shapes[1:], names[1:]):
        if shape != first:
            raise ValueError(
                f"{names[0]} and {name} must have matching leading dimensions, "
                f"got {tuple(first)} and {tuple(shape)}"
            )


def check_number(value, name: str, *, positive: bool = True, allow_zero: bool = False) -> float:
    """``value`` as a finite float; > 0 if ``positive`` (>= 0 with ``allow_zero``),
    else any sign."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and not (v > 0 or (allow_zero and v == 0)):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return v


def check_keys(given: dict, allowed: set, where: str) -> None:
    """Refuse setting names outside ``allowed`` (a typo must not pass silently)."""
    extra = sorted(set(given) - set(allowed))
    if extra:
        raise ValueError(f"unknown {where} setting(s) {extra}; allowed: {sorted(allowed)}")


def check_int(v, name: str, lo: int) -> int:
    """``v`` as an int, refusing bools, fractions, NaN / inf, non-numbers and values
    below ``lo``."""
    if (
        isinstance(v, Tensor)
        and v.numel() == 1
        and not v.is_floating_point()
        and v.dtype != torch.bool
    ):
        v = int(v)
    ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))
    if not ok or int(v) != v or int(v) < lo:
        raise ValueError(f"{name} must be an int >= {lo}, got {v!r}")
    return int(v)
