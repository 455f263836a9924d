"""Each experiment's headline numbers, in one place, and the summary table built from them.

:data:`HEADLINES` maps an experiment to its rows (each experiment's class in
:mod:`protorch.experiments.registry` names its list in :mod:`protorch.experiments.headlines`), rows
``(label, key, method, baselines, paper)``: the metrics key of protorch's result, the method's name,
``((name, key), ...)`` of the baselines measured in the same run, and ``{method name: value}`` where
the paper states a number (Fig. 4's relevance times; Sec. IV-A's operator failed 10 of 10 trials;
the paper states no success rates for Sec. IV-B and IV-C, so their tables have no paper column). In
a method's or baseline's name, ``{optimizer}`` stands for the loop's optimiser and ``{baseline}``
for the loop baseline's (``metrics["settings"]["optimizer"]`` and ``["baseline_optimizer"]``,
registry names; PRO and RWR where the metrics name none), so ``optimizer=epro`` reads "EPRO loop".
:func:`build_summary` turns them into ``metrics["summary"]``; :func:`format_summary` prints it, each
value with the fixed precision of its kind (:func:`format_value`: rates with 3 decimals, times with
1 decimal in s or ms, counts as integers), so any metric a new row names prints alike.
"""

from __future__ import annotations

import math
import os

from ..robots.report import robot_found_lines
from .common import SHARED_OPTIMIZER_KEYS, flatten_metrics, optimizer_label
from .headlines import Headline
from .registry import REGISTRY

__all__ = [
    "Headline",
    "HEADLINES",
    "build_summary",
    "format_summary",
    "format_value",
    "baseline_settings",
    "process_seconds",
]


# {experiment: its rows}, each experiment's class in the registry naming its list (headlines.py)
HEADLINES: dict[str, list[Headline]] = {name: e.headlines for name, e in REGISTRY.items()}


def process_seconds() -> float | None:
    """Seconds since this process started (Python's start and imports included), from Linux's
    ``/proc``; ``None`` where it cannot be read."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(
                f.read().rsplit(")", 1)[1].split()[19]
            )  # field 22: start time after boot
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return None


def baseline_settings(optimizer: dict | None, baseline: dict | None) -> dict | None:
    """What the comparison optimiser (``baseline_optimizer``) runs with: ``{"name", "same":
    {the shared keys it has at the loop optimiser's value}, "own": {the shared keys it sets
    otherwise}}``; ``None`` without a baseline optimiser."""
    if not baseline:
        return None
    optimizer = optimizer or {}
    keys = [k for k in SHARED_OPTIMIZER_KEYS if k in baseline]
    same = {k: baseline[k] for k in keys if k in optimizer and optimizer[k] == baseline[k]}
    return {
        "name": baseline.get("name", "rwr"),
        "optimizer": optimizer.get("name", "pro"),
        "same": same,
        "own": {k: baseline[k] for k in keys if k not in same},
    }


def build_summary(
    name: str,
    metrics: dict,
    *,
    run_dir,
    wall_seconds: float,
    status: str = "ok",
    error: str | None = None,
    baseline: dict | None = None,
) -> dict:
    """``{"status", "run_dir", "wall_seconds" (the run), "process_seconds" (the Python process so
    far, ``None`` where unknown), "headline": {metrics key: {label, method, value, paper}},
    "baseline" (:func:`baseline_settings`, where the run has a baseline optimiser)}``; a key the
    run did not produce (a baseline switched off, a failed run) is left out. The headline is keyed
    by metrics key, so a timing row's keys name it as one."""
    flat = flatten_metrics(metrics)
    names = {
        "optimizer": optimizer_label(flat.get("settings.optimizer") or "pro"),
        "baseline": optimizer_label(flat.get("settings.baseline_optimizer") or "rwr"),
    }
    headline = {}
    rows = REGISTRY[name].headlines if name in REGISTRY else []
    for row in rows:
        for method, key in ((row.method, row.key), *row.baselines):
            method = method.format(**names)
            if key in flat:
                headline[key] = {
                    "label": row.label,
                    "method": method,
                    "value": flat[key],
                    "paper": row.paper.get(method),
                }
    process = process_seconds()
    if baseline is not None and not any(
        optimizer_label(baseline["name"]) in r["method"] for r in headline.values()
    ):
        baseline = None  # its runs are not in this summary (e.g. settings.baselines=[demos_only])
    out = {
        "status": status,
        "run_dir": str(run_dir),
        "wall_seconds": round(float(wall_seconds), 3),
        "process_seconds": None if process is None else round(process, 3),
        "headline": headline,
    }
    if baseline is not None:
        out["baseline"] = baseline
    if robot_found_lines(metrics):  # what protorch found or defaulted for the robot
        out["robot"] = robot_found_lines(metrics)
    if error is not None:
        out["error"] = error
    return out


def _seconds(v: float) -> str:
    return f"{v:.1f} s" if abs(v) >= 1 else f"{v * 1e3:.1f} ms"


def format_value(key: str, v) -> str:
    """``v`` with the fixed precision of the kind its metrics ``key`` names: a rate (``*rate``)
    with 3 decimals, a time (``*seconds*``) with 1 decimal in s (ms below 1 s), an int with
    thousands separators, a bool as yes / no, any other number with 3 significant digits;
    ``None`` as ``-``, NaN as ``n/a`` (e.g. a rate over zero episodes)."""
    last = key.rsplit(".", 1)[-1]
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if not isinstance(v, (int, float)):
        return str(v)
    if isinstance(v, float) and math.isnan(v):
        return "n/a"
    if "seconds" in last:
        return _seconds(float(v))
    if last.endswith("rate"):
        return f"{float(v):.3f}"
    if isinstance(v, int):
        return f"{v:,}"
    if abs(v) >= 1000:
        return f"{v:,.0f}"
    out = f"{v:#.3g}"  # 3 significant digits, trailing zeros kept (1.00) ...
    return (
        out[:-1] if out.endswith(".") else out
    )  # ... but 114, not "114." (a mean of iteration counts)


def _baseline_line(b: dict) -> str:
    opt, base = optimizer_label(b["optimizer"]), optimizer_label(b["name"])
    parts = []
    if b["same"]:
        same = ", ".join(f"{k}={v}" for k, v in b["same"].items())
        parts.append(f"{same} as the {opt} run (baseline_optimizer.<key>=... sets its own)")
    if b["own"]:
        parts.append("its own " + ", ".join(f"{k}={v}" for k, v in b["own"].items()))
    return f"  baseline {base} runs with " + "; ".join(parts) if parts else f"  baseline {base}"


def format_summary(name: str, summary: dict) -> str:
    """A plain-text table: one line per (metric, method), the paper's value where it states one
    (the column only where it states any), the baseline optimiser's settings, then the status,
    the run's and the process's wall times and the run folder."""
    head = summary["headline"]
    paper = any(r["paper"] is not None for r in head.values())
    rows = [("metric", "method", "value", "paper")[: 4 if paper else 3]]
    rows += [
        (r["label"], r["method"], format_value(k, r["value"]), format_value(k, r["paper"]))[
            : 4 if paper else 3
        ]
        for k, r in head.items()
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [f"[protorch] {name} summary"]
    if head:
        lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    if summary.get("baseline"):
        lines.append(_baseline_line(summary["baseline"]))
    status = summary["status"].upper() if summary["status"] != "ok" else "ok"
    if summary.get("error"):
        status += f": {summary['error']}"
    times = f"run {_seconds(summary['wall_seconds'])}"
    if summary.get("process_seconds") is not None:
        process = _seconds(summary["process_seconds"])
        times += f", process {process} (Python's start and imports included)"
    lines += summary.get("robot", [])
    lines.append(f"  status {status}; wall time: {times}")
    lines.append(f"  run folder {summary['run_dir']}")
    return "\n".join(lines)
