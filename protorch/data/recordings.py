"""Timestamped recordings: demonstrations as a robot logs them, read by time and cleaned.

A recordings folder holds one CSV file per demonstration (``*.csv``, read in name order). Its
first line is a header naming the columns: ``time`` (seconds, strictly increasing, any and
varying rate), one column per joint named as the task names it (the arm: ``panda_joint1`` ...
``panda_joint7``, radians, in any order; other columns, e.g. a gripper's, are ignored), and the
environment columns (the arm: ``can_x, can_y, goal_x, goal_y``, metres, one value per row, as
motion capture reads them; the recording's environment is their mean over its rows). A recording
without environment columns takes its environment from ``STEM.json`` beside it:
``{"env": {"can_x": ..., ...}}``.

:func:`read_recordings` reads a folder, checks every file before anything is computed (time that
goes backwards or repeats, NaN rows, a joint outside its limits, a recording shorter than
``min_duration``: one line naming the file and row) and cleans it, each part a setting of
:class:`Cleaning` that can be switched off:

1. idle ends trimmed: where the recording's joint-space speed (smoothed over ``window`` s) first
   and last exceeds ``trim`` times its peak, extended outwards to where the speed falls to twice
   the median speed of the idle parts (the noise: the motion's onset and stop); the ends beyond
   are cut;
2. resampling by time: the kept part, ``samples`` points equally spaced in time;
3. environments as measured: each recording keeps its own environment; recordings whose
   environments lie within ``group_tol`` (single linkage) form one environment of the ProMP fit,
   at their mean. The default tolerance is derived from the data (:func:`group_tolerance`);
4. time alignment of the demonstrations of one environment (and label) by dynamic time warping
   (``dtaidistance``) onto their average timing (:func:`align`).

Each part is reported per recording (``DemoFolder.report``) and drawn by
:func:`protorch.viz.recordings.recordings_figure`. :func:`write_recording` writes one file
atomically (numbers as ``%.17g``, exact for float64).
"""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .files import atomic_write_bytes

__all__ = ["TIME", "Cleaning", "Recording", "align", "clean", "group_envs", "group_tolerance", "is_recordings_folder",
           "read_recording", "read_recordings", "recording_files", "write_recording"]

TIME = "time"
ALIGN_WINDOW = 0.25  # DTW's Sakoe-Chiba band, a fraction of the samples: no warp moves a sample further
EQUAL = 1e-9  # relative: environments closer than this are equal (round-off of a mean over rows)
GAP_RATIO = 3.0  # the derived tolerance needs a gap of this ratio between two merge distances


@dataclass(frozen=True)
class Cleaning:
    """The cleaning of a recordings folder (``task.recordings`` in the app), each part switchable.

    Args:
        trim: idle ends: the speed threshold, a fraction of the recording's peak joint-space speed
            (0 or ``False``: nothing trimmed).
        align: DTW alignment of the demonstrations of one environment (and label).
        samples: points of a resampled demonstration, equally spaced in time.
        min_duration: seconds a recording (and its motion after trimming) lasts at least.
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
        out = {}
        trim = cfg.get("trim", cls.trim)
        if trim is False or trim is None:
            trim = 0.0
        if isinstance(trim, bool) or not isinstance(trim, (int, float)) or not 0 <= trim < 1:
            raise ValueError(f"{name}.trim must be a fraction of the peak speed in [0, 1) or false, got {trim!r}")
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


@dataclass
class Recording:
    """One file as read: ``time (T,)`` seconds, ``values (T, D)`` in the format's column order,
    ``env_rows (T, E)`` (``None`` when the environment comes from the sidecar), ``env (E,)``."""

    path: Path
    time: np.ndarray
    values: np.ndarray
    env: np.ndarray
    env_rows: np.ndarray | None = None
    ignored: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------- files
def recording_files(folder: str | Path) -> list[Path]:
    """The ``*.csv`` files of ``folder`` in natural name order (``demo2`` before ``demo10``)."""
    key = lambda p: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]
    return sorted((p for p in Path(folder).glob("*.csv") if p.is_file()), key=key)


def is_recordings_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds timestamped recordings (``*.csv``) rather than ``trajK.out`` pairs."""
    return Path(folder).is_dir() and bool(recording_files(folder))


def write_recording(path: str | Path, header: Sequence[str], table) -> Path:
    """Write one recording atomically: the ``header`` line, then ``table (T, C)`` as ``%.17g``
    (float64 round-trips exactly)."""
    table = np.asarray(table, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] != len(header) or table.shape[0] < 2:
        raise ValueError(f"write_recording needs a (T >= 2, {len(header)}) table, got {table.shape}")
    buf = io.StringIO()
    buf.write(",".join(header) + "\n")
    np.savetxt(buf, table, fmt="%.17g", delimiter=",")
    return atomic_write_bytes(path, buf.getvalue().encode())


def _first_bad_line(path: Path, lines: list[str], width: int) -> str:
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) != width:
            return f"{path}:{lineno}: expected {width} value(s) as in the header, got {len(parts)}: {line.strip()!r}"
        try:
            [float(p) for p in parts]
        except ValueError:
            return f"{path}:{lineno}: not a number: {line.strip()!r}"
    return f"{path}: unreadable table"


def check_table(where: str, names: Sequence[str], data: np.ndarray, fmt, *, row_name: str = "line",
                first_row: int = 2) -> None:
    """Refuse a recording's table ``data (T, C)`` (columns ``names``): NaN or infinite values,
    time that goes backwards or repeats, values outside the format's bounds. One line naming
    ``where`` and the row (``row_name first_row + i``)."""
    row = lambda i: f"{where}:{first_row + int(i)}" if row_name == "line" else f"{where}, {row_name} {first_row + int(i)}"
    finite = np.isfinite(data)
    if not finite.all():
        i, c = np.argwhere(~finite)[0]
        raise ValueError(f"{row(i)}: {names[c]} is {data[i, c]} (NaN or infinite)")
    if data.shape[0] < 2:
        raise ValueError(f"{where}: a recording needs at least 2 rows, got {data.shape[0]}")
    t = data[:, list(names).index(TIME)]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0])
        how = "repeats" if t[i + 1] == t[i] else "goes backwards from"
        raise ValueError(f"{row(i + 1)}: time {t[i + 1]:.9g} {how} {t[i]:.9g} (the row before); time must increase")
    for cols, bounds, what in ((fmt.columns, fmt.column_bounds, fmt.column_bound_name),
                               (fmt.env_names, fmt.env_bounds, fmt.env_bound_name)):
        if bounds is None:
            continue
        for col, (lo, hi) in zip(cols, bounds):
            if col not in names:
                continue
            v = data[:, list(names).index(col)]
            out = np.flatnonzero((v < lo) | (v > hi))
            if out.size:
                i = int(out[0])
                raise ValueError(f"{row(i)}: {col} = {v[i]:g} lies outside {what} [{lo:g}, {hi:g}]")


def read_recording(path: str | Path, fmt, *, min_duration: float = 0.0) -> Recording:
    """Read and check one recording (:mod:`module docs <protorch.data.recordings>`) against the
    :class:`~protorch.data.demos.DemoFormat` ``fmt``; errors name the file and line."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path} is not a text file (byte {exc.start} cannot be decoded)") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise ValueError(f"{path}: empty, or no header line (time, the joints' names, the environment's)")
    names = [s.strip() for s in lines[0].split(",")]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{path}:1: column(s) {dup} appear more than once")
    if TIME not in names:
        raise ValueError(f"{path}:1: no {TIME!r} column (the header has {names})")
    missing = [c for c in fmt.columns if c not in names]
    if missing:
        raise ValueError(f"{path}:1: no column for joint {missing[0]!r} (the header has {names}; needed: "
                         f"{list(fmt.columns)})")
    env_cols = [c for c in fmt.env_names if c in names]
    if env_cols and len(env_cols) != len(fmt.env_names):
        gone = [c for c in fmt.env_names if c not in names]
        raise ValueError(f"{path}:1: environment column(s) {gone} missing (it has {env_cols}; all or none)")
    try:
        data = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError:
        raise ValueError(_first_bad_line(path, lines, len(names))) from None
    if data.size == 0:
        raise ValueError(f"{path}: a recording needs at least 2 rows, got 0")
    if data.shape[1] != len(names):
        raise ValueError(_first_bad_line(path, lines, len(names)))
    check_table(str(path), names, data, fmt)
    t = data[:, names.index(TIME)]
    if t[-1] - t[0] < min_duration:
        raise ValueError(f"{path}: the recording lasts {t[-1] - t[0]:.3g} s, shorter than the minimum "
                         f"{min_duration:g} s (task.recordings.min_duration)")
    values = data[:, [names.index(c) for c in fmt.columns]]  # (T, D)
    if env_cols:
        env_rows = data[:, [names.index(c) for c in fmt.env_names]]  # (T, E)
        env = np.where(np.ptp(env_rows, 0) == 0, env_rows[0], env_rows.mean(0))  # a constant column: its value
    else:
        env_rows, env = None, _sidecar_env(path, fmt)
    ignored = [n for n in names if n != TIME and n not in fmt.columns and n not in fmt.env_names]
    return Recording(path, t.copy(), values, env, env_rows, ignored)


def _sidecar_env(path: Path, fmt) -> np.ndarray:
    side = path.with_suffix(".json")
    if not side.is_file():
        raise ValueError(f"{path}: no environment columns {list(fmt.env_names)} and no {side.name} beside it "
                         f"(give one or the other)")
    try:
        env = json.loads(side.read_text())["env"]
        vals = [float(env[k]) for k in fmt.env_names]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{side}: expected {{\"env\": {{{', '.join(fmt.env_names)}}}}} ({exc!r})") from None
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{side}: NaN or infinite environment value")
    return np.asarray(vals, dtype=np.float64)


# ----------------------------------------------------------------------------- cleaning
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


def clean(rec: Recording, cleaning: Cleaning) -> tuple[np.ndarray, dict]:
    """Trim the idle ends of one recording and resample it by time: ``(demo (S, D), report)``."""
    t0, t1 = float(rec.time[0]), float(rec.time[-1])
    start, end = t0, t1
    if cleaning.trim > 0:
        grid, sp = speed(rec.time, rec.values, cleaning.window)
        above = np.flatnonzero(sp > cleaning.trim * sp.max())
        if above.size:
            i, j = int(above[0]), int(above[-1])
            idle = sp[sp <= cleaning.trim * sp.max()]
            floor = 2 * float(np.median(idle)) if idle.size else 0.0  # twice the idle parts' typical speed (noise)
            while i > 0 and sp[i - 1] > floor:  # back to the motion's onset: where the speed meets the noise
                i -= 1
            while j < sp.size - 1 and sp[j + 1] > floor:
                j += 1
            start, end = float(grid[i]), float(grid[j])
        else:
            start, end = t0, t0
        if end - start < cleaning.min_duration:
            raise ValueError(f"{rec.path}: it moves for {end - start:.3g} s only (speed above {cleaning.trim:g} of its "
                             f"peak), shorter than the minimum {cleaning.min_duration:g} s "
                             "(task.recordings.min_duration)")
    tt = np.linspace(start, end, cleaning.samples)  # (S,) equally spaced in time
    demo = _interp(tt, rec.time, rec.values)  # (S, D)
    dt = np.diff(rec.time)
    report = {"file": rec.path.name, "rows": int(rec.time.size), "seconds": t1 - t0,
              "rate_hz": float(1.0 / np.median(dt)), "rate_range_hz": [float(1 / dt.max()), float(1 / dt.min())],
              "trimmed_start_s": start - t0, "trimmed_end_s": t1 - end, "kept_s": end - start,
              "env": rec.env.tolist(), "ignored_columns": list(rec.ignored)}
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
        return 0.0, {"rule": f"no gap of ratio >= {GAP_RATIO:g} in the merge distances: equal environments only",
                     "largest_ratio": best}
    tol = float(math.sqrt(pos[k] * pos[k + 1]))
    return tol, {"rule": "geometric mean across the largest gap of the single-linkage merge distances",
                 "below": float(pos[k]), "above": float(pos[k + 1]), "ratio": float(best)}


def group_envs(envs: np.ndarray, tol: float | None) -> tuple[np.ndarray, float, dict]:
    """Group environments ``envs (n, E)`` within ``tol`` (single linkage; ``None``: derived,
    :func:`group_tolerance`): ``(group index (n,), tolerance, report)``, groups numbered in the
    order of their first member."""
    from scipy.cluster.hierarchy import fcluster, linkage

    report = {"tolerance": None, "derived": tol is None}
    if tol is None:
        tol, how = group_tolerance(envs)
        report["how"] = how
    report["tolerance"] = tol
    n = envs.shape[0]
    if n < 2:
        return np.zeros(n, dtype=np.int64), tol, report
    raw = fcluster(linkage(envs, "single"), t=max(tol, EQUAL * (1 + float(np.abs(envs).max()))), criterion="distance")
    order = {}
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
    distance), the warps are smoothed (3 samples) and made monotone, and every demonstration is resampled at
    its warp composed with the inverse of the mean warp. ``(aligned [(S, D)], reports)``: per
    demonstration the largest and mean shift of its phase, its DTW distance to the medoid and its
    pointwise RMS distance to the medoid before and after."""
    try:
        from dtaidistance import dtw_ndim
    except ImportError:
        raise ImportError("time alignment needs dtaidistance: pip install \"protorch[recordings]\", or switch it off "
                          "(task.recordings.align=false)") from None

    n = len(demos)
    if n < 2:
        return [np.asarray(d) for d in demos], [{"warp_max": 0.0, "warp_mean": 0.0} for _ in demos]
    s = demos[0].shape[0]
    band = max(2, int(ALIGN_WINDOW * s))
    series = [np.ascontiguousarray(d, dtype=np.float64) for d in demos]
    dist = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            dist[i, j] = dist[j, i] = dtw_ndim.distance(series[i], series[j], window=band, use_c=True)
    ref = int(dist.sum(1).argmin())
    idx = np.arange(s, dtype=np.float64)
    warps = []
    for k in range(n):
        if k == ref:
            warps.append(idx.copy())
            continue
        path = np.asarray(dtw_ndim.warping_path(series[ref], series[k], window=band, use_c=True))  # (L, 2)
        w = np.bincount(path[:, 0], weights=path[:, 1], minlength=s) / np.bincount(path[:, 0], minlength=s)
        warps.append(_smooth_monotone(w, 3))  # reference index -> this demo's index
    mean = np.mean(warps, 0)  # (S,) the average timing, in each demo's index units
    inv = np.interp(idx, mean, idx)  # common index -> reference index
    out, reports = [], []
    for k, (d, w) in enumerate(zip(series, warps)):
        at = np.interp(inv, idx, w)  # (S,) common index -> this demo's index
        aligned = _interp(at, idx, d)
        shift = np.abs(at - idx) / (s - 1)
        out.append(aligned)
        reports.append({"warp_max": float(shift.max()), "warp_mean": float(shift.mean()), "medoid": k == ref,
                        "dtw_to_medoid": float(dist[k, ref])})
    ref_aligned = out[ref]
    for k in range(n):  # the pointwise (RMS over samples) distance to the medoid, before and after
        reports[k]["rms_to_medoid_before"] = float(np.sqrt(((series[k] - series[ref]) ** 2).sum(1).mean()))
        reports[k]["rms_to_medoid_after"] = float(np.sqrt(((out[k] - ref_aligned) ** 2).sum(1).mean()))
    return out, reports


def read_recordings(folder: str | Path, fmt, cleaning: Cleaning | None = None, *,
                    labeller: Callable[[Tensor, Tensor], int] | None = None, dtype: torch.dtype = torch.float64):
    """Read, check and clean a recordings folder (:mod:`module docs <protorch.data.recordings>`):
    ``(DemoFolder, labels (n,) or None)``. Every file is checked before anything is computed.

    The folder's ``demos[i]`` ``(S, D)`` is recording ``i`` trimmed, resampled and aligned;
    ``envs[i]`` the mean environment of its group (the ProMP fit's); ``report`` holds the
    cleaning settings, the grouping and one entry per recording (its own environment, how much
    was trimmed, its warp); ``stages`` per recording the arrays the figure draws. ``labeller
    (demo (S, D), env (E,)) -> int`` labels each recording (alignment stays within a label)."""
    from .demos import DemoFolder

    cleaning = cleaning or Cleaning()
    folder = Path(folder)
    files = recording_files(folder)
    if not files:
        raise ValueError(f"{folder} holds no *.csv recordings")
    recs = [read_recording(p, fmt, min_duration=cleaning.min_duration) for p in files]  # all checked first
    cleaned = [clean(r, cleaning) for r in recs]
    envs = np.stack([r.env for r in recs])  # (n, E)
    group, _, grouping = group_envs(envs, cleaning.group_tol)
    group_env = np.stack([envs[group == g].mean(0) for g in group])  # (n, E)
    demos = [c[0] for c in cleaned]
    labels = None
    if labeller is not None:
        labels = torch.tensor([int(labeller(torch.as_tensor(d, dtype=dtype), torch.as_tensor(e, dtype=dtype)))
                               for d, e in zip(demos, envs)], dtype=torch.long)  # (n,)
    reports = [c[1] for c in cleaned]
    aligned = list(demos)
    if cleaning.align:
        keys = [(int(g), None if labels is None else int(lab)) for g, lab in
                zip(group, labels if labels is not None else [None] * len(group))]
        for key in dict.fromkeys(keys):
            members = [i for i, k in enumerate(keys) if k == key]
            out, reps = align([demos[i] for i in members])
            for i, a, r in zip(members, out, reps):
                aligned[i] = a
                reports[i].update(r)
    for i, r in enumerate(reports):
        r["group"] = int(group[i])
        r["group_env"] = group_env[i].tolist()
        r["env_offset"] = float(np.linalg.norm(envs[i] - group_env[i]))
        if labels is not None:
            r["label"] = int(labels[i])
    groups = int(group.max()) + 1 if group.size else 0
    spread = [float(np.linalg.norm(envs[group == g] - envs[group == g].mean(0), axis=1).max()) for g in range(groups)]
    report = {"format": "recordings", "cleaning": {f.name: getattr(cleaning, f.name) for f in fields(cleaning)},
              "grouping": {**grouping, "groups": groups, "largest_spread": max(spread) if spread else 0.0},
              "recordings": reports,
              "trimmed_s": {"mean": float(np.mean([r["trimmed_start_s"] + r["trimmed_end_s"] for r in reports])),
                            "max": float(np.max([r["trimmed_start_s"] + r["trimmed_end_s"] for r in reports]))}}
    if cleaning.align:
        report["warp_max"] = float(max(r["warp_max"] for r in reports))
    out = DemoFolder([torch.as_tensor(a, dtype=dtype) for a in aligned],  # (S, D) each
                     torch.as_tensor(group_env, dtype=dtype).reshape(-1, len(fmt.env_names)),  # (n, E)
                     [(p, p) for p in files], list(range(len(files))))
    out.report = report
    out.stages = [{"time": r.time, "raw": r.values, "trimmed": c[0], "aligned": a,
                   "start": c[1]["trimmed_start_s"] + r.time[0], "end": r.time[-1] - c[1]["trimmed_end_s"]}
                  for r, c, a in zip(recs, cleaned, aligned)]
    return out, labels
