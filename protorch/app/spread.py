"""Mean and range over seeds of a sweep's headline numbers: ``python -m protorch.app.report
<sweep> --spread`` after ``python -m protorch -m experiment=<name> seed=0,1,2,3,4 ...``.

Each run's ``metrics.json["summary"]["headline"]`` names its headline numbers (the rows of its
experiment's ``headlines`` in :data:`protorch.experiments.registry.REGISTRY`: label, method, metrics
key, value). Runs that differ only in ``seed`` form one group (a sweep over seeds and another
parameter gives one group per value of that parameter); :func:`seed_spread` gives, per group and
headline key, the number of seeds, the mean, the smallest and the largest value, and the value of
the group's first seed (the single-seed run a figure or a page quotes). :func:`spread_markdown`
prints it with each value at the precision of its kind
(:func:`protorch.experiments.summary.format_value`), and :func:`outside` says which of another run's
numbers fall outside a spread widened by a margin (e.g. one test's resolution, 0.005 for 200
held-out environments).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..experiments.registry import REGISTRY
from ..experiments.summary import format_value
from .sweep import OK, RunRecord, SweepReport

__all__ = ["SEED", "Spread", "headline_values", "seed_spread", "spread_markdown", "outside"]

SEED = "seed"
_PREFIX, _SUFFIX = "summary.headline.", ".value"


@dataclass
class Spread:
    """One headline number over the seeds of one group."""

    key: str  # the metrics key, e.g. "test.success_rate"
    label: str
    method: str
    seeds: list[int]
    values: list[float]  # (S,) in the order of ``seeds`` (ints where the metric is a count)

    @property
    def mean(self) -> float:
        return sum(self.values) / len(self.values)

    @property
    def low(self) -> float:
        return min(self.values)

    @property
    def high(self) -> float:
        return max(self.values)

    @property
    def first(self) -> float:
        """The value at the smallest seed."""
        return self.values[self.seeds.index(min(self.seeds))]


def headline_values(run: RunRecord) -> dict[str, tuple[str, str, float]]:
    """``{metrics key: (label, method, value)}`` of one run's numeric headline entries."""
    out = {}
    for k, v in run.metrics.items():
        if not (k.startswith(_PREFIX) and k.endswith(_SUFFIX)) or isinstance(v, bool):
            continue
        if isinstance(v, (int, float)) and not math.isnan(v):
            key = k[len(_PREFIX) : -len(_SUFFIX)]
            out[key] = (
                str(run.metrics.get(f"{_PREFIX}{key}.label", key)),
                str(run.metrics.get(f"{_PREFIX}{key}.method", "")),
                v,
            )  # an int stays one (71, not 71.0)
    return out


def seed_spread(report: SweepReport) -> dict[tuple, list[Spread]]:
    """``{group: [Spread, ...]}``; a group is the tuple of ``(parameter, value)`` of the swept
    parameters other than ``seed`` (``()`` for a sweep over seeds alone). Runs without
    ``metrics.json`` are left out. Raises ``ValueError`` when ``seed`` is not swept."""
    if SEED not in report.swept:
        raise ValueError(
            f"the sweep under {str(report.root)!r} does not vary the seed (swept: "
            f"{', '.join(report.swept) or 'nothing'}); run it with seed=0,1,2,3,4"
        )
    others = [k for k in report.swept if k != SEED]
    groups: dict[tuple, list[RunRecord]] = {}
    for r in report.runs:
        if r.status == OK:
            groups.setdefault(tuple((k, r.param(k)) for k in others), []).append(r)
    out = {}
    for group, runs in groups.items():
        runs = sorted(runs, key=lambda r: int(r.param(SEED)))
        per_run = [headline_values(r) for r in runs]
        order = [
            k
            for row in getattr(REGISTRY.get(str(runs[0].param("name"))), "headlines", [])
            for k in (row.key, *(b[1] for b in row.baselines))
        ]
        keys = sorted(
            (k for k in per_run[0] if all(k in h for h in per_run)),
            key=lambda k: (order.index(k) if k in order else len(order), k),
        )  # as the run's summary
        out[group] = [
            Spread(
                key=k,
                label=per_run[0][k][0],
                method=per_run[0][k][1],
                seeds=[int(r.param(SEED)) for r in runs],
                values=[h[k][2] for h in per_run],
            )
            for k in keys
        ]
    return out


def spread_markdown(report: SweepReport, spreads: dict[tuple, list[Spread]] | None = None) -> str:
    """A markdown table per group: metric, method, metrics key, mean, range, the first seed's
    value."""
    spreads = seed_spread(report) if spreads is None else spreads
    lines = [f"# Spread over seeds: {report.root}", ""]
    if report.fixed:
        lines += ["Fixed overrides: " + " ".join(f"`{k}={v}`" for k, v in report.fixed.items()), ""]
    for group, rows in spreads.items():
        if group:
            lines += ["## " + ", ".join(f"{k}={v}" for k, v in group), ""]
        if not rows:
            lines += ["(no headline number common to every run)", ""]
            continue
        seeds = rows[0].seeds
        first = min(seeds)
        lines += [
            f"{len(seeds)} seeds: {', '.join(map(str, seeds))}",
            "",
            f"| metric | method | key | mean | range | seed {first} |",
            "|---|---|---|---|---|---|",
        ]
        for s in rows:
            lines.append(
                f"| {s.label} | {s.method} | `{s.key}` | {format_value(s.key, s.mean)} | "
                f"{format_value(s.key, s.low)} - {format_value(s.key, s.high)} | "
                f"{format_value(s.key, s.first)} |"
            )
        lines.append("")
    return "\n".join(lines)


def outside(
    spreads: list[Spread], run: RunRecord, widen: dict[str, float]
) -> dict[str, tuple[float, float, float]]:
    """The keys of ``widen`` whose value in ``run`` lies outside ``[low - w, high + w]`` of the
    spread: ``{key: (value, low - w, high + w)}`` (empty: every one inside). A key missing from
    the spreads or the run is a ``KeyError`` naming it."""
    by_key = {s.key: s for s in spreads}
    values = {k: v[2] for k, v in headline_values(run).items()}
    out = {}
    for key, w in widen.items():
        if key not in by_key or key not in values:
            raise KeyError(
                f"{key!r} is not a headline number of both the spread and the run {run.name!r}"
            )
        lo, hi = by_key[key].low - w, by_key[key].high + w
        if not lo <= values[key] <= hi:
            out[key] = (values[key], lo, hi)
    return out
