"""Which clock a bag's messages are read by (:mod:`protorch.data.import_bag`), said out loud.

Every message of a bag has two times: its header stamp (when the sensor says it was measured;
zero where the publisher left it unset) and its log time (when the recorder received it; one
clock for every topic of the bag). :func:`resolve_stamps` chooses per stream:

- ``header``: the header stamps (a zero stamp is an error);
- ``log``: the log times;
- ``auto`` (the default): the header stamps, except the log times for a stream whose header
  stamps are zero, and for every stream when one stream's stamps do not overlap the joints'
  (two clocks, an offset between them).

A stamp sequence that steps back by at most ``jitter`` seconds (below the latest stamp before
it) is jitter: the stream is sorted by stamp (stable), the count and the largest step back
reported. A larger step back is refused, naming the message and the hint ``--stamp log``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JITTER", "Stream", "describe", "resolve_stamps"]

JITTER = 0.05  # s: the largest step back of a stamp that is sorted as jitter


@dataclass
class Stream:
    """One timed stream of a bag: ``header (K,)`` and ``log (K,)`` int64 nanoseconds (header 0:
    unset), ``data (K, k)`` float64, in the bag's order. ``kind``: how its messages are named in
    errors (``"topic '/joint_states'"``)."""

    kind: str
    header: np.ndarray
    log: np.ndarray
    data: np.ndarray


def _sort_jitter(
    ns: np.ndarray, jitter: float, where: str, kind: str, hint: bool
) -> tuple[np.ndarray, dict]:
    """``(order (K,), report)``: the stable sort of ``ns (K,)`` where every step back is jitter."""
    if ns.size < 2:
        return np.arange(ns.size), {"count": 0, "largest_s": 0.0}
    latest = np.maximum.accumulate(ns)  # (K,)
    back = (latest[:-1] - ns[1:]) / 1e9  # (K - 1,) seconds below the latest stamp before
    bad = np.flatnonzero(back > jitter)
    if bad.size:
        i = int(bad[0]) + 1
        tip = "; the bag's receive times: --stamp log" if hint else ""
        raise ValueError(
            f"{where}: {kind} message {i}: stamp steps back {back[i - 1]:.6g} s below message "
            f"{int(np.argmax(ns[:i]))}'s, more than the jitter tolerance {jitter:g} s (not jitter)"
            f"{tip}"
        )
    return np.argsort(ns, kind="stable"), {
        "count": int((back > 0).sum()),
        "largest_s": float(back.max(initial=0)),
    }


def resolve_stamps(
    streams: dict[str, Stream],
    mode: str,
    where: str,
    *,
    jitter: float = JITTER,
    reference: str | None = None,
) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict]:
    """The time of every stream by ``mode`` (``auto``, ``header`` or ``log``; module docs):
    ``({name: (ns (K,) sorted, data (K, k) in that order)}, report)``. ``reference``: the stream
    the others must overlap (the joints). The report: ``mode``, per stream the clock used
    (``used``), why a stream left its header stamps (``reason``), the streams sorted as jitter
    (``sorted``: count, largest step back)."""
    if mode not in ("auto", "header", "log"):
        raise ValueError(f"--stamp must be auto, header or log, got {mode!r}")
    used, reasons = {}, {}
    for name, s in streams.items():
        zero = np.flatnonzero(s.header <= 0)
        if mode == "header" and zero.size:
            raise ValueError(
                f"{where}: {s.kind} message {int(zero[0])} has a zero header stamp; "
                "--stamp auto or --stamp log reads the bag's receive times"
            )
        used[name] = "log" if mode == "log" or zero.size else "header"
        if mode == "auto" and zero.size:
            reasons[name] = f"{zero.size} of {s.header.size} header stamps are zero"
    pick = lambda n: streams[n].header if used[n] == "header" else streams[n].log
    if mode == "auto" and reference in streams:
        r0, r1 = int(pick(reference).min()), int(pick(reference).max())
        for name, stream in streams.items():
            ns = pick(name)
            if name != reference and (int(ns.min()) > r1 or int(ns.max()) < r0):
                gap = (int(ns.min()) - r0) / 1e9
                reasons["all"] = (
                    f"clock offset: the stamps of {stream.kind} start {gap:+.6g} s from "
                    f"those of {streams[reference].kind} and do not overlap them"
                )
                used = dict.fromkeys(streams, "log")
                break
    out, sorted_ = {}, {}
    for name, s in streams.items():
        ns = pick(name)
        order, rep = _sort_jitter(ns, jitter, where, s.kind, used[name] == "header")
        if rep["count"]:
            sorted_[name] = rep
        out[name] = (ns[order], s.data[order])
    return out, {
        "mode": mode,
        "used": used,
        "reason": reasons,
        "sorted": sorted_,
        "jitter_s": jitter,
    }


def describe(report: dict) -> str:
    """One line: the clock each stream was read by, why, and what was sorted as jitter (a
    report of :func:`resolve_stamps` whose keys name the streams as errors do)."""
    clocks = sorted(set(report["used"].values()))
    text = " and ".join(
        {"header": "header stamps", "log": "the bag's receive times"}[c] for c in clocks
    )
    if len(clocks) > 1:
        text += " (" + ", ".join(f"{n}: {u}" for n, u in report["used"].items()) + ")"
    why = [v if k == "all" else f"{k}: {v}" for k, v in report["reason"].items()]
    parts = [f"time from {text} (--stamp {report['mode']})"] + why
    parts += [
        f"sorted {r['count']} jittered stamp(s) of {n} (up to {r['largest_s'] * 1e3:.3g} ms back)"
        for n, r in report["sorted"].items()
    ]
    return "; ".join(parts)
