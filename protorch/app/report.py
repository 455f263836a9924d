"""One table and one figure for a sweep: ``python -m protorch.app.report runs/multirun/<sweep>``.

A sweep directory (``python -m protorch -m ...``, any launcher or sweeper) holds one folder per
run with ``metrics.json``, the resolved ``config.yaml`` and Hydra's ``.hydra/overrides.yaml``.
:func:`collect` reads them into a :class:`SweepReport`: the swept parameters (overrides or config
entries whose values differ between runs), the fixed overrides, and every run's metrics flattened
to dotted keys (``test.success_rate``). :func:`write_report` writes, atomically,

- ``report.csv``: one row per run, every swept and fixed parameter and every scalar metric;
- ``report.md``: the same rows with the headline columns (objective, success, time);
- ``report.png``: each success and time metric against each swept parameter (one line per value
  of the other swept parameters when there are few, else a scatter);
- ``spread.md`` (``--spread``): mean and range over the swept seeds of each headline number
  (:mod:`protorch.app.spread`).

Runs without ``metrics.json`` (failed, killed or still running) keep their row with the status
``no metrics.json``. No Hydra import: the YAML files are read with OmegaConf
(:mod:`protorch.app.sweep`); the figure is :mod:`protorch.app.report_plot`.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from pathlib import Path
from typing import Sequence

from ..data.files import atomic_write_bytes
from ..figures.paper import save_figure
from .report_plot import plot_sweep
from .spread import spread_markdown
from .sweep import (
    METRICS_FILE,
    MISSING,
    OK,
    OVERRIDES_FILE,
    RunRecord,
    SweepReport,
    collect,
    format_value,
)

__all__ = [
    "METRICS_FILE",
    "MISSING",
    "OK",
    "OUTPUTS",
    "OVERRIDES_FILE",
    "SPREAD_FILE",
    "RunRecord",
    "SweepReport",
    "collect",
    "main",
    "plot_sweep",
    "to_csv",
    "to_markdown",
    "write_report",
]

OUTPUTS = ("report.csv", "report.md", "report.png")
SPREAD_FILE = "spread.md"


# ----------------------------------------------------------------------------- writing
def to_csv(report: SweepReport) -> str:
    rows = report.rows()
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(
            {k: (json.dumps(v) if isinstance(v, (list, dict)) else v) for k, v in row.items()}
        )
    return buf.getvalue()


def to_markdown(report: SweepReport, success: Sequence[str], time: Sequence[str]) -> str:
    ok = sum(r.status == OK for r in report.runs)
    lines = [
        f"# Sweep report: {report.root}",
        "",
        f"{len(report.runs)} runs ({ok} with metrics); swept: "
        f"{', '.join(report.swept) or 'nothing'}.",
        "",
    ]
    if report.fixed:
        lines += [
            "Fixed overrides: "
            + " ".join(f"`{k}={format_value(v)}`" for k, v in report.fixed.items()),
            "",
        ]
    objective = report.objective_metric()
    metric_cols = (["objective.value"] if objective else []) + [
        k for k in (*success, *time) if k != objective
    ]
    names = [f"objective ({objective})" if k == "objective.value" else k for k in metric_cols]
    head = ["run", *report.swept, *names, "status"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in report.runs:
        cells = [
            r.name,
            *(format_value(r.param(k)) for k in report.swept),
            *(format_value(r.metrics.get(k)) for k in metric_cols),
            r.status,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    if report.optuna:
        best = report.optuna.get("best_params") or {}
        lines += [
            "",
            f"Optuna: best value {format_value(report.optuna.get('best_value'))} at "
            + ", ".join(f"`{k}={format_value(v)}`" for k, v in best.items()),
        ]
    return "\n".join(lines) + "\n"


def write_report(
    report: SweepReport,
    out_dir: str | Path | None = None,
    *,
    success: Sequence[str] | None = None,
    time: Sequence[str] | None = None,
    figure: bool = True,
) -> dict[str, Path]:
    """Write ``report.csv``, ``report.md`` and (``figure``, when something was swept) ``report.png``
    into ``out_dir`` (default: the sweep directory), each atomically; return their paths."""
    out = Path(out_dir) if out_dir is not None else report.root
    succ, tim = report.headline(success, time)  # validates given keys before writing anything
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / OUTPUTS[0], "md": out / OUTPUTS[1]}
    atomic_write_bytes(paths["csv"], to_csv(report).encode())
    atomic_write_bytes(paths["md"], to_markdown(report, succ, tim).encode())
    if figure:
        objective = report.objective_metric()
        first = [objective] if objective in report.metric_keys else []
        fig = plot_sweep(report, first + [k for k in (*succ, *tim) if k != objective])
        if fig is not None:
            paths["png"] = out / OUTPUTS[2]
            save_figure(fig, paths["png"])
    return paths


# ----------------------------------------------------------------------------- command line
def _keys(values: list[str] | None) -> list[str] | None:
    if not values:
        return None
    return [k for v in values for k in v.split(",") if k]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m protorch.app.report",
        description="Collect the runs of a sweep (python -m protorch -m ...) into report.csv, "
        "report.md and "
        "report.png (success and time against each swept parameter).",
    )
    ap.add_argument(
        "sweep_dir", help="the sweep's hydra.sweep.dir, e.g. runs/multirun/point_particle__<time>"
    )
    ap.add_argument(
        "--out", default=None, help="where to write the report (default: the sweep directory)"
    )
    ap.add_argument(
        "--success",
        action="append",
        help="success metric key(s), comma-separated "
        "(default: every *success / *success_rate metric, e.g. test.success_rate)",
    )
    ap.add_argument(
        "--time", action="append", help="time metric key(s) (default: every *seconds metric)"
    )
    ap.add_argument("--no-figure", action="store_true", help="write the tables only")
    ap.add_argument(
        "--spread",
        action="store_true",
        help="also spread.md: mean and range over the swept "
        "seeds of each headline number (protorch.app.spread)",
    )
    args = ap.parse_args(argv)
    try:
        report = collect(args.sweep_dir)
        spread = (
            spread_markdown(report) if args.spread else None
        )  # refused (no seed swept) before writing
        paths = write_report(
            report,
            args.out,
            success=_keys(args.success),
            time=_keys(args.time),
            figure=not args.no_figure,
        )
        if spread is not None:
            paths["spread"] = atomic_write_bytes(
                Path(args.out or report.root) / SPREAD_FILE, spread.encode()
            )
    except (OSError, ValueError) as exc:
        print(f"protorch.app.report: error: {exc}", file=sys.stderr)
        return 2
    print(paths["md"].read_text(), end="")
    if spread is not None:
        print("\n" + spread, end="")
    print("\nwrote " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
