"""The figure of :mod:`protorch.app.report`: each headline metric against each swept parameter."""

from __future__ import annotations

import json
from collections.abc import Sequence

from .sweep import OK, SUCCESS_METRIC, SweepReport, format_value

__all__ = ["numeric", "plot_sweep"]


def numeric(v) -> float | None:
    """``v`` as a float when it is a number or a bool, else ``None``."""
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)):
        return float(v)
    return None


def plot_sweep(report: SweepReport, metrics: Sequence[str], *, max_lines: int = 6):
    """A figure with one panel per (metric, swept parameter): rows are ``metrics``, columns the
    swept parameters. Returns the matplotlib figure (``None`` when nothing was swept)."""
    if not report.swept or not metrics:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in report.runs if r.status == OK]
    rows, cols = len(metrics), len(report.swept)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False)
    for j, p in enumerate(report.swept):
        xs_raw = [r.param(p) for r in runs]
        nums = [numeric(x) for x in xs_raw]
        numeric_x = all(v is not None for v in nums)
        if numeric_x:
            xv = [v for v in nums if v is not None]
            log = min(xv) > 0 and max(xv) / min(xv) >= 10
        else:
            cats = sorted({json.dumps(x, default=str) for x in xs_raw})
            xv = [float(cats.index(json.dumps(x, default=str))) for x in xs_raw]
            log = False
        others = [q for q in report.swept if q != p]
        groups: dict[str, list[int]] = {}
        for i, r in enumerate(runs):
            label = ", ".join(f"{q}={format_value(r.param(q))}" for q in others)
            groups.setdefault(label, []).append(i)
        lines = len(groups) <= max_lines
        for i_m, m in enumerate(metrics):
            ax = axes[i_m, j]
            for label, idx in groups.items():
                pts = sorted((xv[i], numeric(runs[i].metrics.get(m))) for i in idx)
                pts = [(x, y) for x, y in pts if y is not None]
                if not pts:
                    continue
                x, y = zip(*pts)
                if lines:
                    ax.plot(x, y, "-o", ms=4, lw=1.2, label=label or None)
                else:
                    ax.scatter(x, y, s=14, color="tab:blue")
            if log:
                ax.set_xscale("log")
            if not numeric_x:
                ax.set_xticks(
                    range(len(cats)),
                    [json.loads(c) if c.startswith('"') else c for c in cats],
                    rotation=20,
                    fontsize=7,
                )
            ax.set_xlabel(p)
            ax.set_ylabel(m, fontsize=8)
            if SUCCESS_METRIC.search(m):
                ax.set_ylim(-0.03, 1.03)
            if lines and others and i_m == 0:
                ax.legend(fontsize=6)
    fig.suptitle(f"{report.root.name}: {len(runs)} runs", fontsize=10)
    fig.tight_layout()
    return fig
