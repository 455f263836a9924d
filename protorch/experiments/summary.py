"""Each experiment's headline numbers, in one place, and the summary table built from them.

:data:`HEADLINES` maps an experiment to rows ``(label, key, method, baselines, paper)``: the
metrics key of protorch's result, the method's name, ``((name, key), ...)`` of the baselines
measured in the same run, and ``{method name: value}`` where the paper states a number (Fig. 4's
relevance times; Sec. IV-A's operator failed 10 of 10 trials; the paper states no success rates for
Sec. IV-B and IV-C). In a method's or baseline's name, ``{optimizer}`` stands for the loop's
optimiser and ``{baseline}`` for the loop baseline's (``metrics["settings"]["optimizer"]`` and
``["baseline_optimizer"]``, registry names; PRO and RWR where the metrics name none), so
``optimizer=epro`` reads "EPRO loop".
:func:`build_summary` turns them into ``metrics["summary"]``; :func:`format_summary` prints it.
"""

from __future__ import annotations

from typing import NamedTuple

from .common import flatten_metrics, optimizer_label

__all__ = ["Headline", "HEADLINES", "build_summary", "format_summary"]


class Headline(NamedTuple):
    label: str
    key: str
    method: str
    baselines: tuple = ()
    paper: dict = {}


HEADLINES: dict[str, list[Headline]] = {
    "fig3_toy": [
        Headline("irrelevant std, final / initial", "pro.irrelevant_std_ratio", "PRO",
                 (("RWR", "rwr.irrelevant_std_ratio"),)),
        Headline("final reward", "pro.final_reward", "PRO", (("RWR", "rwr.final_reward"),)),
    ],
    "fig4_window": [
        Headline("relevance time [s]", "pro.relevance_seconds", "PRO", (("RWPO", "rwpo.relevance_seconds"),),
                 {"PRO": 0.02, "RWPO": 84.47}),
        Headline("mean passes start, window, end", "pro.success", "PRO", (("RWPO", "rwpo.success"),
                                                                           ("demos", "demos.success_rate"))),
        Headline("iterations", "pro.iterations", "PRO", (("RWPO", "rwpo.iterations"),)),
    ],
    "beam_window": [
        Headline("success rate", "optimized.samples_success_rate", "PRO samples",
                 (("demonstrations", "demos.success_rate"),), {"demonstrations": 0.0}),
        Headline("teleoperation success", "teleop.assisted_success_rate", "guided by PRO",
                 (("unassisted", "teleop.unassisted_success_rate"),
                  ("guided by demos", "teleop.assisted_by_demos_promp_success_rate"))),
    ],
    "point_particle": [
        Headline("held-out success", "test.success_rate", "{optimizer} loop",
                 (("demos only", "baselines.demos_only.test.success_rate"),
                  ("{baseline} loop", "baselines.rwr.test.success_rate"))),
        Headline("moving-environment success", "dynamic.success_rate", "{optimizer} loop",
                 (("demos only", "baselines.demos_only.dynamic.success_rate"),
                  ("{baseline} loop", "baselines.rwr.dynamic.success_rate"))),
        Headline("the authors' moving test (wall, hole, goal moving)", "dynamic_paper.success_rate",
                 "{optimizer} loop"),
    ],
    "self_improve": [
        Headline("held-out success", "test.success_rate", "loop",
                 (("demos only", "demos_only.test.success_rate"),)),
    ],
    "arm_reach": [
        Headline("held-out success", "test.success_rate", "{optimizer} loop, labels",
                 (("labels dropped", "baselines.labels_off.test.success_rate"),
                  ("loop without labels", "baselines.labels_off_loop.test.success_rate"))),
        Headline("moving-environment success", "dynamic.success_rate", "{optimizer} loop, labels",
                 (("labels dropped", "baselines.labels_off.dynamic.success_rate"),
                  ("loop without labels", "baselines.labels_off_loop.dynamic.success_rate"))),
        Headline("side switches (labels)", "dynamic.switches", "{optimizer} loop, labels",
                 (("labels dropped", "baselines.labels_off.dynamic.switches"),
                  ("loop without labels", "baselines.labels_off_loop.dynamic.switches"))),
        Headline("side switches (geometric)", "dynamic.switches_geometric", "{optimizer} loop, labels",
                 (("labels dropped", "baselines.labels_off.dynamic.switches_geometric"),
                  ("loop without labels", "baselines.labels_off_loop.dynamic.switches_geometric"))),
        Headline("held-out success in MuJoCo", "physics.test.success_rate", "{optimizer} loop, labels"),
        Headline("moving success in MuJoCo", "physics.dynamic.success_rate", "{optimizer} loop, labels"),
        Headline("MuJoCo episodes with a contact", "physics.dynamic.contacts", "{optimizer} loop, labels"),
    ],
}


def build_summary(name: str, metrics: dict, *, run_dir, wall_seconds: float, status: str = "ok",
                  error: str | None = None) -> dict:
    """``{"status", "run_dir", "wall_seconds", "headline": {metrics key: {label, method, value,
    paper}}}``; a key the run did not produce (a baseline switched off, a failed run) is left out.
    The headline is keyed by metrics key, so a timing row's keys name it as one."""
    flat = flatten_metrics(metrics)
    names = {"optimizer": optimizer_label(flat.get("settings.optimizer") or "pro"),
             "baseline": optimizer_label(flat.get("settings.baseline_optimizer") or "rwr")}
    headline = {}
    for row in HEADLINES.get(name, []):
        for method, key in ((row.method, row.key), *row.baselines):
            method = method.format(**names)
            if key in flat:
                headline[key] = {"label": row.label, "method": method, "value": flat[key],
                                 "paper": row.paper.get(method)}
    out = {"status": status, "run_dir": str(run_dir), "wall_seconds": round(float(wall_seconds), 3),
           "headline": headline}
    if error is not None:
        out["error"] = error
    return out


def _cell(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def format_summary(name: str, summary: dict) -> str:
    """A plain-text table: one line per (metric, method), the paper's value where it states one,
    then the status, the run folder and the wall time."""
    rows = [("metric", "method", "value", "paper")]
    rows += [(r["label"], r["method"], _cell(r["value"]), _cell(r["paper"])) for r in summary["headline"].values()]
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = [f"[protorch] {name} summary"]
    lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    status = summary["status"].upper() if summary["status"] != "ok" else "ok"
    if summary.get("error"):
        status += f": {summary['error']}"
    lines.append(f"  status {status}; wall time {summary['wall_seconds']:.1f} s")
    lines.append(f"  run folder {summary['run_dir']}")
    return "\n".join(lines)
