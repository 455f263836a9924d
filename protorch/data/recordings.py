"""Timestamped recordings: demonstrations as a robot logs them, read by time and cleaned.

A recordings folder holds one CSV file per demonstration (``*.csv``, read in name order). Its
first line is a header naming the columns: ``time`` (seconds, strictly increasing, any and
varying rate), one column per joint named as the task names it (the arm: its robot's joint names,
radians, in any order; other columns, e.g. a gripper's, are ignored), and the
environment columns (the arm: ``can_x, can_y, goal_x, goal_y``, metres, one value per row, as
motion capture reads them; the recording's environment is their mean over its rows). A recording
without environment columns takes its environment from ``STEM.json`` beside it:
``{"env": {"can_x": ..., ...}}``.

:func:`read_recordings` reads a folder, checks every file before anything is computed (time that
goes backwards or repeats, NaN rows, a joint outside its limits, a recording shorter than
``min_duration``: one line naming the file and row; a recording too short or motionless is
excluded, :mod:`protorch.data.quality`) and cleans it, each part a setting of
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
:func:`protorch.figures.recordings.recordings_figure`. :func:`write_recording` writes one file
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
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .cleaning import Cleaning, TooShort, align, clean, group_envs, group_tolerance
from .files import atomic_write_bytes
from .formats import DemoFolder
from .quality import exclusion, flags

__all__ = [
    "TIME",
    "Cleaning",
    "Recording",
    "align",
    "clean",
    "group_envs",
    "group_tolerance",
    "is_recordings_folder",
    "read_recording",
    "read_recordings",
    "recording_files",
    "write_recording",
]

TIME = "time"
IMPORT_SUFFIX = ".import.json"  # the importer's report beside a recording: STEM.import.json


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
    imported: dict | None = None  # the importer's report (``STEM.import.json`` beside the file)


# ----------------------------------------------------------------------------- files
def recording_files(folder: str | Path) -> list[Path]:
    """The ``*.csv`` files of ``folder`` in natural name order (``demo2`` before ``demo10``)."""
    key = lambda p: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]
    return sorted((p for p in Path(folder).glob("*.csv") if p.is_file()), key=key)


def is_recordings_folder(folder: str | Path) -> bool:
    """Whether ``folder`` holds timestamped recordings (``*.csv``) rather than
    ``trajK.out`` pairs."""
    return Path(folder).is_dir() and bool(recording_files(folder))


def write_recording(path: str | Path, header: Sequence[str], table) -> Path:
    """Write one recording atomically: the ``header`` line, then ``table (T, C)`` as ``%.17g``
    (float64 round-trips exactly)."""
    table = np.asarray(table, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] != len(header) or table.shape[0] < 2:
        raise ValueError(
            f"write_recording needs a (T >= 2, {len(header)}) table, got {table.shape}"
        )
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
            return (
                f"{path}:{lineno}: expected {width} value(s) as in the header, "
                f"got {len(parts)}: {line.strip()!r}"
            )
        try:
            [float(p) for p in parts]
        except ValueError:
            return f"{path}:{lineno}: not a number: {line.strip()!r}"
    return f"{path}: unreadable table"


def check_table(
    where: str,
    names: Sequence[str],
    data: np.ndarray,
    fmt,
    *,
    row_name: str = "line",
    first_row: int = 2,
) -> None:
    """Refuse a recording's table ``data (T, C)`` (columns ``names``): NaN or infinite values,
    time that goes backwards or repeats, values outside the format's bounds. One line naming
    ``where`` and the row (``row_name first_row + i``)."""
    row = lambda i: (
        f"{where}:{first_row + int(i)}"
        if row_name == "line"
        else f"{where}, {row_name} {first_row + int(i)}"
    )
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
        raise ValueError(
            f"{row(i + 1)}: time {t[i + 1]:.9g} {how} {t[i]:.9g} (the row before); time must "
            "increase"
        )
    for cols, bounds, what in (
        (fmt.columns, fmt.column_bounds, fmt.column_bound_name),
        (fmt.env_names, fmt.env_bounds, fmt.env_bound_name),
    ):
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
        raise ValueError(
            f"{path} is not a text file (byte {exc.start} cannot be decoded)"
        ) from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise ValueError(
            f"{path}: empty, or no header line (time, the joints' names, the environment's)"
        )
    names = [s.strip() for s in lines[0].split(",")]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{path}:1: column(s) {dup} appear more than once")
    if TIME not in names:
        raise ValueError(f"{path}:1: no {TIME!r} column (the header has {names})")
    missing = [c for c in fmt.columns if c not in names]
    if missing:
        raise ValueError(
            f"{path}:1: no column for joint {missing[0]!r} (the header has {names}; needed: "
            f"{list(fmt.columns)})"
        )
    env_cols = [c for c in fmt.env_names if c in names]
    if env_cols and len(env_cols) != len(fmt.env_names):
        gone = [c for c in fmt.env_names if c not in names]
        raise ValueError(
            f"{path}:1: environment column(s) {gone} missing (it has {env_cols}; all or none)"
        )
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
        raise ValueError(
            f"{path}: the recording lasts {t[-1] - t[0]:.3g} s, shorter than the minimum "
            f"{min_duration:g} s (task.recordings.min_duration)"
        )
    values = data[:, [names.index(c) for c in fmt.columns]]  # (T, D)
    if env_cols:
        env_rows = data[:, [names.index(c) for c in fmt.env_names]]  # (T, E)
        env = np.where(
            np.ptp(env_rows, 0) == 0, env_rows[0], env_rows.mean(0)
        )  # a constant column: its value
    else:
        env_rows, env = None, _sidecar_env(path, fmt)
    ignored = [n for n in names if n != TIME and n not in fmt.columns and n not in fmt.env_names]
    return Recording(path, t.copy(), values, env, env_rows, ignored, _import_report(path))


def _import_report(path: Path) -> dict | None:
    side = path.with_name(path.stem + IMPORT_SUFFIX)
    if not side.is_file():
        return None
    try:
        return dict(json.loads(side.read_text()))
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{side}: not an import report ({exc})") from None


def summary_lines(reports: Sequence[dict], excluded: Sequence[dict]) -> list[str]:
    """One line per excluded recording and per recording with a finding
    (:mod:`protorch.data.quality`)."""
    out = [f"excluded {e['file']}: {e['reason']}" for e in excluded]
    for r in reports:
        if "env_moved" in r:
            out.append(
                f"{r['file']}: the environment moved {r['env_moved']['drift'] * 1e3:.1f} mm during "
                "it "
                f"(scatter {r['env_moved']['scatter'] * 1e3:.1f} mm)"
            )
        if "env_stream_ends_s" in r:
            out.append(
                f"{r['file']}: the environment stream ends at {r['env_stream_ends_s']:.2f} s of "
                f"{r['seconds']:.2f} s (held since)"
            )
        for j in r.get("jumps", []):
            out.append(
                f"{r['file']}: {j['joint']} jumps by {j['step']:.3g} rad at {j['time_s']:.3f} s"
            )
        for g in r.get("gaps", []):
            out.append(f"{r['file']}: no sample for {g['seconds']:.3g} s at {g['time_s']:.3f} s")
    return out


def _sidecar_env(path: Path, fmt) -> np.ndarray:
    side = path.with_suffix(".json")
    if not side.is_file():
        raise ValueError(
            f"{path}: no environment columns {list(fmt.env_names)} and no {side.name} beside it "
            f"(give one or the other)"
        )
    try:
        env = json.loads(side.read_text())["env"]
        vals = [float(env[k]) for k in fmt.env_names]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(
            f'{side}: expected {{"env": {{{", ".join(fmt.env_names)}}}}} ({exc!r})'
        ) from None
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{side}: NaN or infinite environment value")
    return np.asarray(vals, dtype=np.float64)


def read_recordings(
    folder: str | Path,
    fmt,
    cleaning: Cleaning | None = None,
    *,
    labeller: Callable[[Tensor, Tensor], int] | None = None,
    dtype: torch.dtype = torch.float64,
):
    """Read, check and clean a recordings folder (:mod:`module docs <protorch.data.recordings>`):
    ``(DemoFolder, labels (n,) or None)``. Every file is checked before anything is computed; a
    recording that does not move or is too short (:mod:`protorch.data.quality`) is excluded and
    listed in ``report["excluded"]`` as ``{file, reason}``, the others cleaned as if it were not
    there; a folder where none remains is refused naming every exclusion. The findings
    (environment moved, stream ended, joint jumps, gaps) are in each recording's entry and, one
    line each with the exclusions, in ``report["summary"]``.

    The folder's ``demos[i]`` ``(S, D)`` is recording ``i`` trimmed, resampled and aligned;
    ``envs[i]`` the mean environment of its group (the ProMP fit's); ``report`` holds the
    cleaning settings, the grouping and one entry per recording (its own environment, how much
    was trimmed, its warp); ``stages`` per recording the arrays the figure draws. ``labeller
    (demo (S, D), env (E,)) -> int`` labels each recording (alignment stays within a label)."""
    cleaning = cleaning or Cleaning()
    folder = Path(folder)
    files = recording_files(folder)
    if not files:
        raise ValueError(f"{folder} holds no *.csv recordings")
    recs = [read_recording(p, fmt) for p in files]  # all checked first
    excluded, kept, cleaned = [], [], []
    for r in recs:
        why = exclusion(r.time, r.values, cleaning.min_duration, fmt.columns)
        if why is None:
            try:
                cleaned.append(clean(r, cleaning))
                kept.append(r)
                continue
            except TooShort as exc:
                why = exc.reason
        excluded.append(
            {"file": r.path.name, "reason": why, **flags(r.time, r.values, r.env_rows, fmt.columns)}
        )
    if not kept:
        raise ValueError(
            f"{folder}: no recording remains to train on (excluded: "
            + "; ".join(f"{e['file']}: {e['reason']}" for e in excluded)
            + ")"
        )
    recs, files = kept, [r.path for r in kept]
    for r, c in zip(recs, cleaned):
        c[1].update(flags(r.time, r.values, r.env_rows, fmt.columns))
        if r.imported is not None:
            c[1]["import"] = r.imported
    envs = np.stack([r.env for r in recs])  # (n, E)
    group, _, grouping = group_envs(envs, cleaning.group_tol)
    group_env = np.stack([envs[group == g].mean(0) for g in group])  # (n, E)
    demos = [c[0] for c in cleaned]
    labels = None
    if labeller is not None:
        labels = torch.tensor(
            [
                int(labeller(torch.as_tensor(d, dtype=dtype), torch.as_tensor(e, dtype=dtype)))
                for d, e in zip(demos, envs)
            ],
            dtype=torch.long,
        )  # (n,)
    reports = [c[1] for c in cleaned]
    aligned = list(demos)
    if cleaning.align:
        keys = [
            (int(g), None if labels is None else int(lab))
            for g, lab in zip(group, labels if labels is not None else [None] * len(group))
        ]
        for key in dict.fromkeys(keys):
            members = [i for i, k in enumerate(keys) if k == key]
            warped, reps = align([demos[i] for i in members])
            for i, a, rep in zip(members, warped, reps):
                aligned[i] = a
                reports[i].update(rep)
    for i, rep in enumerate(reports):
        rep["group"] = int(group[i])
        rep["group_env"] = group_env[i].tolist()
        rep["env_offset"] = float(np.linalg.norm(envs[i] - group_env[i]))
        if labels is not None:
            rep["label"] = int(labels[i])
    groups = int(group.max()) + 1 if group.size else 0
    spread = [
        float(np.linalg.norm(envs[group == g] - envs[group == g].mean(0), axis=1).max())
        for g in range(groups)
    ]
    report: dict[str, Any] = {
        "format": "recordings",
        "cleaning": {f.name: getattr(cleaning, f.name) for f in fields(cleaning)},
        "grouping": {
            **grouping,
            "groups": groups,
            "largest_spread": max(spread) if spread else 0.0,
        },
        "recordings": reports,
        "excluded": excluded,
        "summary": summary_lines(reports, excluded),
        "trimmed_s": {
            "mean": float(np.mean([r["trimmed_start_s"] + r["trimmed_end_s"] for r in reports])),
            "max": float(np.max([r["trimmed_start_s"] + r["trimmed_end_s"] for r in reports])),
        },
    }
    if cleaning.align:
        report["warp_max"] = float(max(r["warp_max"] for r in reports))
    demo_folder = DemoFolder(
        [torch.as_tensor(a, dtype=dtype) for a in aligned],  # (S, D) each
        torch.as_tensor(group_env, dtype=dtype).reshape(-1, len(fmt.env_names)),  # (n, E)
        [(p, p) for p in files],
        list(range(len(files))),
    )
    demo_folder.report = report
    demo_folder.stages = [
        {
            "time": r.time,
            "raw": r.values,
            "trimmed": c[0],
            "aligned": a,
            "start": c[1]["trimmed_start_s"] + r.time[0],
            "end": r.time[-1] - c[1]["trimmed_end_s"],
        }
        for r, c, a in zip(recs, cleaned, aligned)
    ]
    return demo_folder, labels
