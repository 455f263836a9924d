"""Quality checks of timestamped recordings before training (:mod:`protorch.data.recordings`).

Each check is stated in absolute terms, in the recording's own units:

- **motionless**: the largest range of a joint over the recording (max - min) is below
  :data:`MIN_MOTION` rad; the recording is excluded (encoder noise alone spans about 1e-3 rad);
- **too short**: the recording, or its motion after trimming, lasts less than ``min_duration``;
  excluded;
- **environment moved**: the mean of the environment's rows over the recording's last quarter
  differs from the first quarter's by more than :data:`MOVE_FACTOR` times their scatter (the
  rows' standard deviation within the quarters, as a vector norm) and by more than
  :data:`MOVE_FLOOR`; reported (the drift and the scatter), not excluded;
- **environment stream ended**: the environment's rows stop changing more than
  :data:`STREAM_END_S` s and more than 10 % of the recording before its last joint row (a
  stream that ended, held since); reported;
- **joint jumps**: a step between two rows faster than :data:`JUMP_SPEED` rad/s and larger than
  :data:`JUMP_MIN` rad (an encoder wrap, a glitch), and **gaps**: an interval longer than 5 times
  the median interval and than 0.05 s (dropped samples); reported with their times.

Arrays are numpy float64; nothing is read or written here.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "JUMP_MIN",
    "JUMP_SPEED",
    "MIN_MOTION",
    "MOVE_FACTOR",
    "MOVE_FLOOR",
    "STREAM_END_S",
    "exclusion",
    "flags",
]

MIN_MOTION = 0.02  # rad: a recording whose every joint spans less than this is motionless
MOVE_FACTOR = 3.0  # the environment's drift over the recording against its scatter
MOVE_FLOOR = 1e-3  # the environment's units (m): smaller drifts are never reported
STREAM_END_S = (
    1.0  # s: an environment stream held this long (and 10 % of the recording) before the end
)
JUMP_SPEED = 10.0  # rad/s: 4 times the Panda's fastest joint velocity limit (2.61 rad/s)
JUMP_MIN = 0.05  # rad: smaller steps are never jumps
_MAX_LISTED = 10  # jumps and gaps listed per recording


def exclusion(time: np.ndarray, values: np.ndarray, min_duration: float, names) -> str | None:
    """Why a recording ``time (T,)``, ``values (T, D)`` (joints ``names``) is excluded before
    cleaning, or ``None``."""
    seconds = float(time[-1] - time[0])
    if seconds < min_duration:
        return (
            f"the recording lasts {seconds:.3g} s, shorter than the minimum {min_duration:g} s "
            "(task.recordings.min_duration)"
        )
    span = np.ptp(values, axis=0)  # (D,)
    if float(span.max()) < MIN_MOTION:
        return (
            f"motionless: its joints span at most {float(span.max()):.3g} rad ("
            f"{names[int(span.argmax())]}), "
            f"less than {MIN_MOTION:g} rad"
        )
    return None


def flags(time: np.ndarray, values: np.ndarray, env_rows: np.ndarray | None, names) -> dict:
    """The reported (not excluding) findings of one recording: ``{"env_moved": {...}}``,
    ``{"env_stream_ends_s": ...}``, ``{"jumps": [...]}``, ``{"gaps": [...]}`` where found;
    ``{}`` for a clean recording. ``names``: the joints' names (``D``); times in seconds from
    the recording's first row."""
    out: dict = {}
    t = time - time[0]
    if env_rows is not None and env_rows.shape[0] >= 8:
        q = max(2, env_rows.shape[0] // 4)
        first, last = env_rows[:q], env_rows[-q:]  # (q, E)
        drift = float(np.linalg.norm(last.mean(0) - first.mean(0)))
        scatter = float(np.linalg.norm(0.5 * (first.std(0) + last.std(0))))
        if drift > MOVE_FLOOR and drift > MOVE_FACTOR * scatter:
            out["env_moved"] = {"drift": drift, "scatter": scatter}
        changed = np.flatnonzero(np.any(np.diff(env_rows, axis=0) != 0, axis=1))
        if changed.size:
            stop = float(t[changed[-1] + 1])
            held = float(t[-1]) - stop
            if held > STREAM_END_S and held > 0.1 * float(t[-1]):
                out["env_stream_ends_s"] = stop
    dt = np.diff(t)  # (T - 1,)
    step = np.abs(np.diff(values, axis=0))  # (T - 1, D)
    fast = (step > JUMP_MIN) & (step > JUMP_SPEED * dt[:, None])
    rows, cols = np.nonzero(fast)
    if rows.size:
        out["jumps"] = [
            {
                "time_s": float(t[r + 1]),
                "joint": str(names[c]),
                "step": float(values[r + 1, c] - values[r, c]),
            }
            for r, c in list(zip(rows.tolist(), cols.tolist()))[:_MAX_LISTED]
        ]
    med = float(np.median(dt)) if dt.size else 0.0
    gap = np.flatnonzero((dt > 5 * med) & (dt > 0.05))
    if gap.size:
        out["gaps"] = [
            {"time_s": float(t[i]), "seconds": float(dt[i])} for i in gap[:_MAX_LISTED].tolist()
        ]
    return out
