"""One table and one figure for a sweep: ``python -m protorch.app.report runs/multirun/<sweep>``.

A sweep directory (``python -m protorch -m ...``, any launcher or sweeper) holds one folder per
run with ``metrics.json``, the resolved ``config.yaml`` and Hydra's ``.hydra/overrides.yaml``.
:func:`collect` reads them into a :class:`SweepReport`: the swept parameters (overrides or config
entries whose values differ between runs), the fixed overrides, and every run's metrics flattened
to dotted keys (``test.success_rate``). :func:`write_report` writes, atomically,

- ``report.csv``: one row per run, every swept and fixed parameter and every scalar metric;
- ``report.md``: the same rows with the headline columns (objective, success, time);
- ``report.png``: each success and time metric against each swept parameter (one line per value
  of the other swept parameters when there are few, else a scatter).

Runs without ``metrics.json`` (failed, killed or still running) keep their row with the status
``no metrics.json``. No Hydra import: the YAML files are read with OmegaConf.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from omegaconf import OmegaConf

from ..data.files import atomic_write_bytes
from ..experiments.common import flatten_metrics
from ..viz.paper import save_figure

__all__ = ["RunRecord", "SweepReport", "collect", "write_report", "plot_sweep", "main"]

METRICS_FILE = "metrics.json"
OVERRIDES_FILE = Path(".hydra") / "overrides.yaml"
OUTPUTS = ("report.csv", "report.md", "report.png")
OK = "ok"
MISSING = f"no {METRICS_FILE}"
_SUCCESS = re.compile(r"(^|\.)(success|success_rate)$")
_TIME = re.compile(r"(^|\.)seconds$")


@dataclass
class RunRecord:
    """One run of a sweep: where it is, what it was told, what it measured."""

    name: str  # path relative to the sweep directory, e.g. "3"
    path: Path
    overrides: dict[str, str]  # key -> value as typed on the command line
    config: dict  # the resolved config, flattened to dotted keys
    metrics: dict  # metrics.json flattened to dotted keys; {} when missing
    status: str  # "ok" or "no metrics.json"

    def param(self, key: str):
        """The value a parameter had in this run: the resolved config's, else the override's."""
        if key in self.config:
            return self.config[key]
        return self.overrides.get(key)


@dataclass
class SweepReport:
    """The runs of a sweep, the parameters that vary between them and the ones that do not."""

    root: Path
    runs: list[RunRecord]
    swept: list[str]  # parameters whose values differ between runs
    fixed: dict[str, object] = field(default_factory=dict)  # overrides shared by every run
    optuna: dict | None = None  # optimization_results.yaml of an Optuna sweep

    @property
    def metric_keys(self) -> list[str]:
        """Every scalar metric key of any run, sorted."""
        keys = {k for r in self.runs for k, v in r.metrics.items() if _scalar(v)}
        return sorted(keys)

    def objective_metric(self) -> str | None:
        names = {r.metrics.get("objective.metric") for r in self.runs} - {None}
        return next(iter(names)) if len(names) == 1 else None

    def headline(self, success: Sequence[str] | None = None, time: Sequence[str] | None = None):
        """``(success keys, time keys)``: the given ones (each must exist in some run), else every
        ``*success`` / ``*success_rate`` and ``*seconds`` metric at depth <= 2 outside
        ``baselines.``, sorted."""
        keys = self.metric_keys
        for given in (success, time):
            for k in given or ():
                if k not in keys:
                    raise ValueError(f"no run has a metric {k!r}; metrics: {', '.join(keys)}")

        def auto(pattern):
            seen: list[str] = []
            for r in self.runs:
                for k, v in r.metrics.items():
                    if (pattern.search(k) and _scalar(v) and k.count(".") <= 1
                            and not k.startswith(("baselines.", "objective.")) and k not in seen):
                        seen.append(k)
            return sorted(seen)

        return list(success) if success else auto(_SUCCESS), list(time) if time else auto(_TIME)

    def rows(self) -> list[dict]:
        """One dict per run: ``run``, ``status``, the swept and fixed parameters, every metric."""
        out = []
        for r in self.runs:
            row: dict = {"run": r.name, "status": r.status}
            for k in self.swept:
                row[k] = r.param(k)
            for k, v in self.fixed.items():
                row[k] = v
            for k in self.metric_keys:
                row[k] = r.metrics.get(k)
            out.append(row)
        return out


# ----------------------------------------------------------------------------- reading
def _scalar(v) -> bool:
    return isinstance(v, (bool, int, float, str)) or v is None


def _natural(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _find_runs(root: Path) -> list[Path]:
    """Folders holding ``metrics.json`` or ``.hydra/overrides.yaml``; hidden folders (``.submitit``)
    and the insides of a run (``baselines/rwr``) are not searched."""
    found, stack = [], [root]
    while stack:
        d = stack.pop()
        if (d / METRICS_FILE).is_file() or (d / OVERRIDES_FILE).is_file():
            found.append(d)
            continue
        stack.extend(p for p in d.iterdir() if p.is_dir() and not p.name.startswith("."))
    return sorted(found, key=lambda p: _natural(str(p.relative_to(root))))


def _parse_overrides(path: Path) -> dict[str, str]:
    items = OmegaConf.to_container(OmegaConf.load(path))
    if not isinstance(items, list):
        raise ValueError(f"{path}: expected a list of Hydra overrides (key=value), got {type(items).__name__}")
    out = {}
    for item in items:
        text = str(item)
        if text.startswith("~"):  # a deletion: ~key or ~key=value
            out[text[1:].split("=", 1)[0]] = "<deleted>"
            continue
        if "=" not in text:
            raise ValueError(f"{path}: {text!r} is not a key=value override")
        key, value = text.split("=", 1)
        out[key.lstrip("+")] = value
    return out


def _read_config(run: Path) -> dict:
    for path in (run / "config.yaml", run / ".hydra" / "config.yaml"):
        if path.is_file():
            cfg = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
            if not isinstance(cfg, dict):
                raise ValueError(f"{path}: expected a mapping, got {type(cfg).__name__}")
            cfg.pop("hydra", None)
            return flatten_metrics(cfg)
    return {}


def _read_metrics(run: Path) -> dict | None:
    path = run / METRICS_FILE
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON ({exc}); is this a protorch run?") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object of metrics, got {type(data).__name__}")
    return flatten_metrics(data)


def _same(values: list) -> bool:
    reps = {json.dumps(v, sort_keys=True, default=str) for v in values}
    return len(reps) == 1


def collect(sweep_dir: str | Path) -> SweepReport:
    """Read every run under ``sweep_dir`` (a Hydra multirun directory); see the module docstring.

    Raises ``FileNotFoundError`` / ``NotADirectoryError`` for a missing path or a file, and
    ``ValueError`` for a folder with no runs, no run with metrics, or an unreadable run file.
    """
    root = Path(sweep_dir).expanduser()
    if not root.exists():
        raise FileNotFoundError(f"sweep directory {str(root)!r} does not exist")
    if not root.is_dir():
        raise NotADirectoryError(f"{str(root)!r} is a file, not a sweep directory")
    dirs = _find_runs(root)
    if not dirs:
        raise ValueError(
            f"no runs under {str(root)!r}: a sweep directory (python -m protorch -m ...) holds one folder "
            f"per run with {METRICS_FILE} and {OVERRIDES_FILE}; is this the sweep's hydra.sweep.dir?"
        )
    runs = []
    for d in dirs:
        metrics = _read_metrics(d)
        ov = _parse_overrides(d / OVERRIDES_FILE) if (d / OVERRIDES_FILE).is_file() else {}
        name = str(d.relative_to(root)) if d != root else d.name
        runs.append(RunRecord(name=name, path=d, overrides=ov, config=_read_config(d), metrics=metrics or {},
                              status=OK if metrics is not None else MISSING))
    if all(r.status != OK for r in runs):
        raise ValueError(
            f"none of the {len(runs)} run(s) under {str(root)!r} has a {METRICS_FILE}: they failed, were "
            "killed or are still running (see each run's log)"
        )
    # parameters: every overridden key, plus config entries that differ between runs
    keys: list[str] = []
    for r in runs:
        keys += [k for k in r.overrides if k not in keys]
    if len(runs) > 1:
        config_keys = sorted({k for r in runs for k in r.config})
        keys += [k for k in config_keys if k not in keys and not _same([r.config.get(k) for r in runs])]
    swept = [k for k in keys if not _same([r.param(k) for r in runs])]
    fixed = {k: runs[0].param(k) for k in keys if k not in swept}
    optuna = None
    results = root / "optimization_results.yaml"
    if results.is_file():
        optuna = OmegaConf.to_container(OmegaConf.load(results))
    return SweepReport(root=root, runs=runs, swept=swept, fixed=fixed, optuna=optuna)


# ----------------------------------------------------------------------------- writing
def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return str(v).replace("|", "\\|")


def to_csv(report: SweepReport) -> str:
    rows = report.rows()
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (json.dumps(v) if isinstance(v, (list, dict)) else v) for k, v in row.items()})
    return buf.getvalue()


def to_markdown(report: SweepReport, success: Sequence[str], time: Sequence[str]) -> str:
    ok = sum(r.status == OK for r in report.runs)
    lines = [f"# Sweep report: {report.root}", "",
             f"{len(report.runs)} runs ({ok} with metrics); swept: {', '.join(report.swept) or 'nothing'}.", ""]
    if report.fixed:
        lines += ["Fixed overrides: " + " ".join(f"`{k}={_fmt(v)}`" for k, v in report.fixed.items()), ""]
    objective = report.objective_metric()
    metric_cols = (["objective.value"] if objective else []) + [k for k in (*success, *time) if k != objective]
    names = [f"objective ({objective})" if k == "objective.value" else k for k in metric_cols]
    head = ["run", *report.swept, *names, "status"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in report.runs:
        cells = [r.name, *(_fmt(r.param(k)) for k in report.swept), *(_fmt(r.metrics.get(k)) for k in metric_cols),
                 r.status]
        lines.append("| " + " | ".join(cells) + " |")
    if report.optuna:
        best = report.optuna.get("best_params") or {}
        lines += ["", f"Optuna: best value {_fmt(report.optuna.get('best_value'))} at "
                  + ", ".join(f"`{k}={_fmt(v)}`" for k, v in best.items())]
    return "\n".join(lines) + "\n"


def _numeric(v) -> float | None:
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
        numeric_x = all(_numeric(x) is not None for x in xs_raw)
        if numeric_x:
            xv = [_numeric(x) for x in xs_raw]
            log = min(xv) > 0 and max(xv) / min(xv) >= 10
        else:
            cats = sorted({json.dumps(x, default=str) for x in xs_raw})
            xv = [float(cats.index(json.dumps(x, default=str))) for x in xs_raw]
            log = False
        others = [q for q in report.swept if q != p]
        groups: dict[str, list[int]] = {}
        for i, r in enumerate(runs):
            label = ", ".join(f"{q}={_fmt(r.param(q))}" for q in others)
            groups.setdefault(label, []).append(i)
        lines = len(groups) <= max_lines
        for i_m, m in enumerate(metrics):
            ax = axes[i_m, j]
            for label, idx in groups.items():
                pts = sorted((xv[i], _numeric(runs[i].metrics.get(m))) for i in idx)
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
                ax.set_xticks(range(len(cats)), [json.loads(c) if c.startswith('"') else c for c in cats],
                              rotation=20, fontsize=7)
            ax.set_xlabel(p)
            ax.set_ylabel(m, fontsize=8)
            if _SUCCESS.search(m):
                ax.set_ylim(-0.03, 1.03)
            if lines and others and i_m == 0:
                ax.legend(fontsize=6)
    fig.suptitle(f"{report.root.name}: {len(runs)} runs", fontsize=10)
    fig.tight_layout()
    return fig


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
        description="Collect the runs of a sweep (python -m protorch -m ...) into report.csv, report.md and "
                    "report.png (success and time against each swept parameter).",
    )
    ap.add_argument("sweep_dir", help="the sweep's hydra.sweep.dir, e.g. runs/multirun/point_particle__<time>")
    ap.add_argument("--out", default=None, help="where to write the report (default: the sweep directory)")
    ap.add_argument("--success", action="append", help="success metric key(s), comma-separated "
                    "(default: every *success / *success_rate metric, e.g. test.success_rate)")
    ap.add_argument("--time", action="append", help="time metric key(s) (default: every *seconds metric)")
    ap.add_argument("--no-figure", action="store_true", help="write the tables only")
    args = ap.parse_args(argv)
    try:
        report = collect(args.sweep_dir)
        paths = write_report(report, args.out, success=_keys(args.success), time=_keys(args.time),
                             figure=not args.no_figure)
    except (OSError, ValueError) as exc:
        print(f"protorch.app.report: error: {exc}", file=sys.stderr)
        return 2
    print(paths["md"].read_text(), end="")
    print("\nwrote " + ", ".join(str(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
