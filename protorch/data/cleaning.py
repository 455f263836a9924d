"""The cleaning of timestamped recordings (:mod:`protorch.data.recordings`), each part switchable:
idle ends trimmed by a speed threshold, resampling by time, environments grouped within a
tolerance (derived from the data by default), time alignment by dynamic time warping
(``dtaidistance``). Arrays are numpy float64; no file is read or written here."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from itertools import pairwise
from typing import Any, Sequence

import numpy as np

from ..errors import ProtorchError

__all__ = [
    "ALIGN_WINDOW",
    "Cleaning",
    "TooShort",
    "align",
    "clean",
    "group_envs",
    "group_tolerance",
    "speed",
    "split_idle",
]

ALIGN_WINDOW = (
    0.25  # DTW's Sakoe-Chiba band, a fraction of the samples: no warp moves a sample further
)
EQUAL = 1e-9  # relative: environments closer than this are equal (round-off of a mean over rows)
GAP_RATIO = 3.0  # the derived tolerance needs a gap of this ratio between two merge distances


class TooShort(ProtorchError, ValueError):
    """A recording whose motion after trimming is shorter than ``min_duration`` (the folder
    reader excludes it; :attr:`reason` without the file name)."""

    def __init__(self, path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.reason = reason


@dataclass(frozen=True)
class Cleaning:
    """The cleaning of a recordings folder (``task.recordings`` in the app), each part switchable.

    Args:
        trim: idle ends: the speed threshold, a fraction of the recording's peak joint-space speed
            (0 or ``False``: nothing trimmed).
        align: DTW alignment of the demonstrations of one environment (and label).
        samples: points of a resampled demonstration, equally spaced in time.
        min_duration: seconds a recording (and its motion after trimming) lasts at least (a
            shorter one is excluded by the folder reader).
        group_tol: environments closer than this (the environment's units, metres for the arm) are
            one environment of the ProMP fit; ``None`` (``auto``): derived from the data.
        window: seconds of the moving average applied before the speed is measured.
    """

    trim: float = 0.05
    align: bool = True
    samples: int = 200
    min_duration: float = 0.5
    group_tol: float | None = None
    window: float = 0.05

    @classmethod
    def from_config(cls, cfg: dict | None, name: str = "task.recordings") -> Cleaning:
        """Validate a settings dict (unknown keys, types, ranges: one line naming the setting)."""
        cfg = dict(cfg or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ValueError(f"{name}: unknown setting(s) {unknown}; known: {sorted(known)}")
        out: dict[str, Any] = {}
        trim = cfg.get("trim", cls.trim)
        if trim is False or trim is None:
            trim = 0.0
        if isinstance(trim, bool) or not isinstance(trim, (int, float)) or not 0 <= trim < 1:
            raise ValueError(
                f"{name}.trim must be a fraction of the peak speed in [0, 1) or false, got {trim!r}"
            )
        out["trim"] = float(trim)
        if not isinstance(cfg.get("align", cls.align), bool):
            raise ValueError(f"{name}.align must be true or false, got {cfg['align']!r}")
        out["align"] = cfg.get("align", cls.align)
        samples = cfg.get("samples", cls.samples)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
            raise ValueError(f"{name}.samples must be an int >= 2, got {samples!r}")
        out["samples"] = samples
        for key in ("min_duration", "window"):
            v = cfg.get(key, getattr(cls, key))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ValueError(f"{name}.{key} must be a number of seconds > 0, got {v!r}")
            out[key] = float(v)
        tol = cfg.get("group_tol", None)
        if tol in (None, "auto"):
            tol = None
        elif isinstance(tol, bool) or not isinstance(tol, (int, float)) or not tol >= 0:
            raise ValueError(f"{name}.group_tol must be auto or a distance >= 0, got {tol!r}")
        out["group_tol"] = None if tol is None else float(tol)
        return cls(**out)

    def off(self) -> Cleaning:
        """The same settings with trimming and alignment switched off (resampling by time stays)."""
        return Cleaning(0.0, False, self.samples, self.min_duration, self.group_tol, self.window)


def _interp(t_new: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of ``y (T, D)`` at ``t_new (S,)``: ``(S, D)``."""
    return np.stack([np.interp(t_new, t, y[:, d]) for d in range(y.shape[1])], 1)


def speed(time: np.ndarray, values: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """The joint-space speed of a recording: ``(grid (G,), speed (G,))`` on a grid of step
    ``window / 10`` s, the values smoothed by a moving average of ``window`` s first."""
    h = window / 10
    grid = np.arange(time[0], time[-1] + 0.5 * h, h)  # (G,)
    q = _interp(grid, time, values)  # (G, D)
    k = max(1, round(window / h))
    if grid.size > k:
        pad = np.pad(q, ((k // 2, k - 1 - k // 2), (0, 0)), mode="edge")
        kernel = np.full(k, 1.0 / k)
        q = np.stack([np.convolve(pad[:, d], kernel, mode="valid") for d in range(q.shape[1])], 1)
    v = np.gradient(q, h, axis=0) if grid.size > 1 else np.zeros_like(q)  # (G, D)
    return grid, np.linalg.norm(v, axis=1)


def clean(rec, cleaning: Cleaning) -> tuple[np.ndarray, dict]:
    """Trim the idle ends of one recording (a :class:`~protorch.data.recordings.Recording`) and
    resample it by time: ``(demo (S, D), report)``."""
    t0, t1 = float(rec.time[0]), float(rec.time[-1])
    start, end = t0, t1
    if cleaning.trim > 0:
        grid, sp = speed(rec.time, rec.values, cleaning.window)
        above = np.flatnonzero(sp > cleaning.trim * sp.max())
        if above.size:
            i, j = int(above[0]), int(above[-1])
            idle = sp[sp <= cleaning.trim * sp.max()]
            floor = (
                2 * float(np.median(idle)) if idle.size else 0.0
            )  # twice the idle parts' typical speed (noise)
            while (
                i > 0 and sp[i - 1] > floor
            ):  # back to the motion's onset: where the speed meets the noise
                i -= 1
            while j < sp.size - 1 and sp[j + 1] > floor:
                j += 1
            start, end = float(grid[i]), float(grid[j])
        else:
            start, end = t0, t0
        if end - start < cleaning.min_duration:
            raise TooShort(
                rec.path,
                f"it moves for {end - start:.3g} s only (speed above {cleaning.trim:g} of its "
                f"peak), shorter than the minimum {cleaning.min_duration:g} s "
                "(task.recordings.min_duration)",
            )
    tt = np.linspace(start, end, cleaning.samples)  # (S,) equally spaced in time
    demo = _interp(tt, rec.time, rec.values)  # (S, D)
    dt = np.diff(rec.time)
    report = {
        "file": rec.path.name,
        "rows": int(rec.time.size),
        "seconds": t1 - t0,
        "rate_hz": float(1.0 / np.median(dt)),
        "rate_range_hz": [float(1 / dt.max()), float(1 / dt.min())],
        "trimmed_start_s": start - t0,
        "trimmed_end_s": t1 - end,
        "kept_s": end - start,
        "env": rec.env.tolist(),
        "ignored_columns": list(rec.ignored),
    }
    if rec.env_rows is not None:
        report["env_spread"] = float(np.linalg.norm(rec.env_rows - rec.env, axis=1).max())
    return demo, report


def group_tolerance(envs: np.ndarray) -> tuple[float, dict]:
    """The grouping tolerance derived from the data: the single-linkage merge distances of the
    environments, sorted, split at their largest ratio between neighbours (the first, smallest
    one excluded) when that ratio is at least :data:`GAP_RATIO`: the tolerance is the geometric
    mean of the two sides (the measurement scatter below, distinct environments above). Without
    such a gap: 0 (equal environments only). ``(tolerance, report)``."""
    from scipy.cluster.hierarchy import linkage

    n = envs.shape[0]
    if n < 3:
        return 0.0, {"rule": "fewer than 3 recordings: equal environments only"}
    heights = np.sort(linkage(envs, "single")[:, 2])  # (n - 1,)
    pos = heights[heights > 0]
    best, k = 0.0, -1
    for i in range(1 if pos.size >= 4 else 0, pos.size - 1):
        r = pos[i + 1] / pos[i]
        if r > best:
            best, k = r, i
    if best < GAP_RATIO:
        return 0.0, {
            "rule": f"no gap of ratio >= {GAP_RATIO:g} in the merge distances: equal environments "
            "only",
            "largest_ratio": best,
        }
    tol = float(math.sqrt(pos[k] * pos[k + 1]))
    return tol, {
        "rule": "geometric mean across the largest gap of the single-linkage merge distances",
        "below": float(pos[k]),
        "above": float(pos[k + 1]),
        "ratio": float(best),
    }


def group_envs(envs: np.ndarray, tol: float | None) -> tuple[np.ndarray, float, dict]:
    """Group environments ``envs (n, E)`` within ``tol`` (single linkage; ``None``: derived,
    :func:`group_tolerance`): ``(group index (n,), tolerance, report)``, groups numbered in the
    order of their first member."""
    from scipy.cluster.hierarchy import fcluster, linkage

    report: dict[str, Any] = {"tolerance": None, "derived": tol is None}
    if tol is None:
        tol, how = group_tolerance(envs)
        report["how"] = how
    report["tolerance"] = tol
    n = envs.shape[0]
    if n < 2:
        return np.zeros(n, dtype=np.int64), tol, report
    raw = fcluster(
        linkage(envs, "single"),
        t=max(tol, EQUAL * (1 + float(np.abs(envs).max()))),
        criterion="distance",
    )
    order: dict[int, int] = {}
    group = np.array([order.setdefault(int(g), len(order)) for g in raw], dtype=np.int64)
    return group, tol, report


def _smooth_monotone(w: np.ndarray, k: int) -> np.ndarray:
    if k > 1:
        pad = np.pad(w, (k // 2, k - 1 - k // 2), mode="edge")
        w = np.convolve(pad, np.full(k, 1.0 / k), mode="valid")
    w = np.maximum.accumulate(w)
    return np.clip((w - w[0]) / max(w[-1] - w[0], 1e-12), 0, 1) * (len(w) - 1)


def align(demos: Sequence[np.ndarray]) -> tuple[list[np.ndarray], list[dict]]:
    """Align demonstrations ``(S, D)`` of one environment in time (dynamic time warping,
    ``dtaidistance``, within a band of :data:`ALIGN_WINDOW` of the samples) onto their average
    timing: each is warped to the medoid's (the demonstration with the least summed DTW
    distance), the warps are smoothed (3 samples) and made monotone, and every demonstration is
    resampled at
    its warp composed with the inverse of the mean warp. ``(aligned [(S, D)], reports)``: per
    demonstration the largest and mean shift of its phase, its DTW distance to the medoid and its
    pointwise RMS distance to the medoid before and after."""
    try:
        from dtaidistance import dtw_ndim
    except ImportError:
        raise ImportError(
            'time alignment needs dtaidistance: pip install "protorch[recordings]", or switch it '
            "off "
            "(task.recordings.align=false)"
        ) from None

    n = len(demos)
    if n < 2:
        return [np.asarray(d) for d in demos], [{"warp_max": 0.0, "warp_mean": 0.0} for _ in demos]
    s = demos[0].shape[0]
    band = max(2, int(ALIGN_WINDOW * s))
    series = [np.ascontiguousarray(d, dtype=np.float64) for d in demos]
    dist = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            dist[i, j] = dist[j, i] = dtw_ndim.distance(
                series[i], series[j], window=band, use_c=True
            )
    ref = int(dist.sum(1).argmin())
    idx = np.arange(s, dtype=np.float64)
    warps = []
    for k in range(n):
        if k == ref:
            warps.append(idx.copy())
            continue
        path = np.asarray(
            dtw_ndim.warping_path(series[ref], series[k], window=band, use_c=True)
        )  # (L, 2)
        w = np.bincount(path[:, 0], weights=path[:, 1], minlength=s) / np.bincount(
            path[:, 0], minlength=s
        )
        warps.append(_smooth_monotone(w, 3))  # reference index -> this demo's index
    mean = np.mean(warps, 0)  # (S,) the average timing, in each demo's index units
    inv = np.interp(idx, mean, idx)  # common index -> reference index
    out, reports = [], []
    for k, (d, w) in enumerate(zip(series, warps)):
        at = np.interp(inv, idx, w)  # (S,) common index -> this demo's index
        aligned = _interp(at, idx, d)
        shift = np.abs(at - idx) / (s - 1)
        out.append(aligned)
        reports.append(
            {
                "warp_max": float(shift.max()),
                "warp_mean": float(shift.mean()),
                "medoid": k == ref,
                "dtw_to_medoid": float(dist[k, ref]),
            }
        )
    ref_aligned = out[ref]
    for k in range(n):  # the pointwise (RMS over samples) distance to the medoid, before and after
        reports[k]["rms_to_medoid_before"] = float(
            np.sqrt(((series[k] - series[ref]) ** 2).sum(1).mean())
        )
        reports[k]["rms_to_medoid_after"] = float(
            np.sqrt(((out[k] - ref_aligned) ** 2).sum(1).mean())
        )
    return out, reports


def split_idle(
    time: np.ndarray, values: np.ndarray, idle: float, *, trim: float = 0.05, window: float = 0.05
) -> list[tuple[int, int]]:
    """A session of several demonstrations, ``time (T,)``, ``values (T, D)``, split at idle
    periods: where the joint-space speed (:func:`speed`) stays at or below ``trim`` times its peak
    for at least ``idle`` seconds between two motions, cut at the middle of that period. Returns
    ``[(first row, end row)]`` (end exclusive), one per segment, in time order; ``[(0, T)]``
    without such a period."""
    if not idle > 0:
        raise ValueError(f"--idle must be a number of seconds > 0, got {idle!r}")
    grid, sp = speed(time, values, window)
    moving = sp > trim * sp.max()  # (G,)
    if not moving.any():
        return [(0, int(time.size))]
    first, last = np.flatnonzero(moving)[[0, -1]]
    cuts, i = [], int(first)
    while i < last:
        if moving[i]:
            i += 1
            continue
        j = i
        while not moving[j]:
            j += 1
        if grid[j] - grid[i] >= idle:
            cuts.append(0.5 * (grid[i] + grid[j]))
        i = j
    rows = [0] + [int(np.searchsorted(time, c)) for c in cuts] + [int(time.size)]
    return list(pairwise(rows))
