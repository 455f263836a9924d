"""Reading a sweep for :mod:`protorch.app.report`: one :class:`RunRecord` per run folder
(``metrics.json``, the resolved ``config.yaml``, Hydra's ``.hydra/overrides.yaml``, read with
OmegaConf), gathered by :func:`collect` into a :class:`SweepReport` with the swept and the fixed
parameters."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from omegaconf import OmegaConf

from ..experiments.common import flatten_metrics

__all__ = [
    "METRICS_FILE",
    "MISSING",
    "OK",
    "OVERRIDES_FILE",
    "SUCCESS_METRIC",
    "TIME_METRIC",
    "RunRecord",
    "SweepReport",
    "collect",
    "format_value",
]

METRICS_FILE = "metrics.json"
OVERRIDES_FILE = Path(".hydra") / "overrides.yaml"
OK = "ok"
MISSING = f"no {METRICS_FILE}"
SUCCESS_METRIC = re.compile(r"(^|\.)(success|success_rate)$")
TIME_METRIC = re.compile(r"(^|\.)seconds$")


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
                    if (
                        pattern.search(k)
                        and _scalar(v)
                        and k.count(".") <= 1
                        and not k.startswith(("baselines.", "objective."))
                        and k not in seen
                    ):
                        seen.append(k)
            return sorted(seen)

        return list(success) if success else auto(SUCCESS_METRIC), list(time) if time else auto(
            TIME_METRIC
        )

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
        raise ValueError(
            f"{path}: expected a list of Hydra overrides (key=value), got {type(items).__name__}"
        )
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
            f"no runs under {str(root)!r}: a sweep directory (python -m protorch -m ...) holds one "
            "folder "
            f"per run with {METRICS_FILE} and {OVERRIDES_FILE}; is this the sweep's "
            "hydra.sweep.dir?"
        )
    runs = []
    for d in dirs:
        metrics = _read_metrics(d)
        ov = _parse_overrides(d / OVERRIDES_FILE) if (d / OVERRIDES_FILE).is_file() else {}
        name = str(d.relative_to(root)) if d != root else d.name
        runs.append(
            RunRecord(
                name=name,
                path=d,
                overrides=ov,
                config=_read_config(d),
                metrics=metrics or {},
                status=OK if metrics is not None else MISSING,
            )
        )
    if all(r.status != OK for r in runs):
        raise ValueError(
            f"none of the {len(runs)} run(s) under {str(root)!r} has a {METRICS_FILE}: they "
            "failed, were "
            "killed or are still running (see each run's log)"
        )
    # parameters: every overridden key, plus config entries that differ between runs
    keys: list[str] = []
    for r in runs:
        keys += [k for k in r.overrides if k not in keys]
    if (
        len(runs) > 1
    ):  # ... except entries that only follow an overridden key (``${optimizer.beta}``)
        config_keys = sorted({k for r in runs for k in r.config})
        followed = [[r.param(k) for r in runs] for k in keys]
        keys += [
            k
            for k in config_keys
            if k not in keys
            and not _same([r.config.get(k) for r in runs])
            and [r.config.get(k) for r in runs] not in followed
        ]
    swept = [k for k in keys if not _same([r.param(k) for r in runs])]
    fixed = {k: runs[0].param(k) for k in keys if k not in swept}
    optuna: dict | None = None
    results = root / "optimization_results.yaml"
    if results.is_file():
        optuna = cast(dict, OmegaConf.to_container(OmegaConf.load(results)))  # a YAML mapping
    return SweepReport(root=root, runs=runs, swept=swept, fixed=fixed, optuna=optuna)


def format_value(v) -> str:
    """A value as a table cell or a legend entry: 4 significant digits, JSON for lists and dicts."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return str(v).replace("|", "\\|")
