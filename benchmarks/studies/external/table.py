"""Tables of docs/external.md from the JSON files of benchmarks/studies/external/run.py (any Python
with
protorch; fancy_gym is not needed):

    python benchmarks/studies/external/table.py benchmarks/studies/results/external/*.json --at 1600
    python benchmarks/studies/external/table.py FILES... --at 1600 --doc docs/external.md --marker
    summary

Per (task, optimiser), over its runs (contexts x seeds) that reached ``--at`` episodes: how many
final means succeed, the median return of the mean at ``--at`` episodes, how many runs drew a
succeeding sample by then and the median episode of the first one, the median best sample's
return, and for box pushing the median distances of the mean's box to its goal (cm, rad).
``--curve 200,400,800,1600`` prints the median return of the mean against episodes instead.
``--doc F --marker M`` writes the table between ``<!-- M -->`` and ``<!-- /M -->`` in ``F``
(atomically; the markers must exist), with the command and the commits of the runs.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import statistics
import sys
from collections import defaultdict
from pathlib import Path


def load(paths: list[str]) -> tuple[list[dict], list[dict]]:
    runs, metas = [], []
    for p in paths:
        data = json.loads(Path(p).read_text())
        metas.append(data["meta"])
        for r in data["runs"]:
            runs.append(
                {"commit": data["meta"].get("commit", "?"), **r, "file": Path(p).name}
            )  # a run's own commit first
    return runs, metas


def at(run: dict, episodes: int) -> dict | None:
    """The run's last check of the mean at or before ``episodes`` (None if the run stopped short
    of ``episodes`` without spending them: a budget it was not given)."""
    if run["episodes"] < episodes - run.get("samples", 20) and run.get("stopped") is None:
        return None
    points = [c for c in run["curve"] if c["episodes"] <= episodes]
    return points[-1] if points else None


def median(xs: list[float]) -> float | None:
    xs = [x for x in xs if x is not None and not math.isnan(x)]
    return statistics.median(xs) if xs else None


def fmt(x, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def summary(runs: list[dict], episodes: int) -> list[str]:
    groups: dict[tuple[str, str], list[tuple[dict, dict]]] = defaultdict(list)
    for r in runs:
        c = at(r, episodes)
        if c is not None and r["episodes"] + 20 > episodes:  # the run had this budget
            groups[(r["task"], r["optimizer"])].append((r, c))
    head = (
        "| task | optimiser | runs (contexts x seeds) | final mean succeeds | median return of the "
        "mean | "
        "a sample succeeded | median episode of the first success | median best sample's return | "
        "box: median mean's distance to goal (cm, rad) |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|---|"]
    for (task, opt), items in sorted(groups.items()):
        n = len(items)
        ctx = sorted({r["context"] for r, _ in items})
        seeds = sorted({r["seed"] for r, _ in items})
        firsts = [
            r["first_success"]
            for r, _ in items
            if r["first_success"] is not None and r["first_success"] <= episodes
        ]
        box = "-"
        if task == "box_pushing":
            pos, rot = (
                median([c["mean_pos_dist"] * 100 for _, c in items]),
                median([c["mean_rot_dist"] for _, c in items]),
            )
            box = f"{fmt(pos)}, {fmt(rot, '.2f')}"
        lines.append(
            f"| {task} | {opt} | {n} ({len(ctx)} x {len(seeds)}) | "
            f"{sum(c['mean_success'] for _, c in items)} / {n} | "
            f"{fmt(median([c['mean_return'] for _, c in items]))} | {len(firsts)} / {n} | "
            f"{fmt(median(firsts), '.0f')} | "
            f"{fmt(median([c['best_return'] for _, c in items]))} | {box} |"
        )
    return lines


def curve(runs: list[dict], points: list[int]) -> list[str]:
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in runs:
        if not r.get(
            "partial"
        ):  # a run cut short (still going, or stopped) is not a run of its budget
            groups[(r["task"], r["optimizer"])].append(r)
    lines = [
        "| task | optimiser | runs | " + " | ".join(f"{p}" for p in points) + " |",
        "|---|---|---|" + "---|" * len(points),
    ]
    for (task, opt), rs in sorted(groups.items()):
        cells = []
        for p in points:
            cs = [at(r, p) for r in rs if r["episodes"] + 20 > p]
            cells.append(fmt(median([c["mean_return"] for c in cs if c is not None])))
        lines.append(f"| {task} | {opt} | {len(rs)} | " + " | ".join(cells) + " |")
    return lines


def write_doc(doc: Path, marker: str, text: str) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
    from protorch.data.files import atomic_write_bytes

    src = doc.read_text()
    start, end = f"<!-- {marker} -->", f"<!-- /{marker} -->"
    if start not in src or end not in src:
        raise SystemExit(f"{doc}: markers {start} ... {end} not found")
    head, rest = src.split(start, 1)
    _, tail = rest.split(end, 1)
    atomic_write_bytes(doc, (head + start + "\n" + text + "\n" + end + tail).encode())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--at", type=int, default=1600, help="episodes the summary is read at")
    ap.add_argument(
        "--curve", default="", help="comma-separated episode counts: the mean's median return there"
    )
    ap.add_argument("--doc", default=None)
    ap.add_argument("--marker", default="summary")
    args = ap.parse_args(argv)
    runs, metas = load(args.files)
    lines = (
        curve(runs, [int(x) for x in args.curve.split(",")])
        if args.curve
        else summary(runs, args.at)
    )
    commits = sorted({r["commit"] for r in runs} or {m.get("commit", "?") for m in metas})
    cmd = "python benchmarks/studies/external/table.py " + shlex.join(
        sys.argv[1:] if argv is None else argv
    )
    runs_cmds = sorted({m["command"] for m in metas})
    first = commits[0].split("+")[
        0
    ]  # the docs' convention (tests/docs_tables.py): commit and command above the table
    comment = f'<!-- measured: commit={first} command="{cmd}" -->'
    text = (
        comment
        + "\n"
        + "\n".join(lines)
        + "\n\n"
        + f"Table: `{cmd}`; runs at commit(s) {', '.join(commits)}:\n"
        + "\n".join(
            f"`{c}`" + ("" if i == len(runs_cmds) - 1 else ",") for i, c in enumerate(runs_cmds)
        )
    )
    if args.doc:
        write_doc(Path(args.doc), args.marker, text)
    print(text)


if __name__ == "__main__":
    main()
