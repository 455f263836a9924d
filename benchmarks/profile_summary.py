"""Where the main job's time goes, from a cProfile of the whole run (on demand):

    python benchmarks/profile_summary.py --record main.prof experiment=point_particle threads=1
    python benchmarks/profile_summary.py main.prof [other.prof]

``--record OUT`` runs ``python -m protorch`` with the overrides that follow in this process
under cProfile with a CPU-time clock (``time.process_time``: another program's load does not
count, which a wall clock on a shared machine would; at ``threads=1`` the run has no other
compute thread and no worker process), writes the profile to ``OUT`` and summarises it.
Otherwise each argument is a profile (this script's or ``python -m cProfile -o``'s).

Prints one row per part of the run: the cumulative seconds of the functions that make it (as
cProfile counts them: its own overhead included, so shares rather than seconds) and its share
of the whole. With two profiles (e.g. of two checkouts) the columns stand side by side. A part
a profile lacks (a function the other version does not have) reads ``-``.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import runpy
import sys
import time
from pathlib import Path

# (label, [(file suffix, function name), ...]): a part's seconds are the largest cumulative time
# of its functions (they nest), so no call is counted twice
PARTS = [
    ("whole run", [("protorch/__main__.py", "<module>")]),
    ("imports and config (before the experiment)", []),
    ("both loops (PRO, RWR)", [("protorch/loop/__init__.py", "self_improve")]),
    (
        "  evaluating the samples (loop.phases.sample_costs)",
        [("protorch/loop/phases.py", "sample_costs")],
    ),
    (
        "    trajectories (ProMP basis x weights)",
        [
            ("protorch/primitives/promp.py", "trajectory"),
            ("protorch/loop/phases.py", "sample_trajectory"),
        ],
    ),
    ("    the task's costs, every objective", [("protorch/tasks/point_particle.py", "costs")]),
    (
        "    the task's cost, one objective alone",
        [("protorch/tasks/point_particle.py", "objective_cost")],
    ),
    (
        "    signed distance to the wall",
        [("protorch/tasks/point_particle.py", "signed_distance_to_wall")],
    ),
    ("  the optimisers' tell (updates, relevance, next ask)", [("protorch/optim/base.py", "tell")]),
    ("    normal draws (the generator)", [("protorch/optim/base.py", "_randn")]),
    ("    relevance (Pearson)", [("protorch/optim/functional.py", "pearson_relevance")]),
    ("    update (Eq. 4-6)", [("protorch/optim/functional.py", "pro_update")]),
    ("  input checks (finite values)", [("protorch/checks.py", "check_tensor")]),
    (
        "moving tests (both moving-environment tests, 3 maps)",
        [("protorch/control/particle.py", "run_episodes")],
    ),
    ("figures", [("protorch/experiments/point_particle.py", "figures")]),
    ("  animated GIFs", [("protorch/figures/online.py", "write_episode_gif")]),
]


def part_seconds(stats: pstats.Stats) -> dict[str, float | None]:
    cum: dict[tuple[str, str], float] = {}
    for (file, _, name), (_, _, _, ct, _) in stats.stats.items():
        key = (file.replace("\\", "/"), name)
        cum[key] = max(cum.get(key, 0.0), ct)
    out: dict[str, float | None] = {}
    for label, funcs in PARTS:
        found = [
            ct
            for (file, name), ct in cum.items()
            for suffix, fn in funcs
            if file.endswith(suffix) and name == fn
        ]
        out[label] = max(found) if found else None
    run = max((ct for (file, name), ct in cum.items() if name == "run_experiment"), default=None)
    if out["whole run"] is not None and run is not None:
        out["imports and config (before the experiment)"] = out["whole run"] - run
    return out


def record(out: str, overrides: list[str]) -> None:
    """Profile ``python -m protorch OVERRIDES`` in this process on a CPU-time clock into ``out``."""
    sys.argv = ["protorch", *overrides]
    here = (
        Path(__file__).resolve().parent
    )  # benchmarks/ off the path: its modules' names must not shadow others
    sys.path[:] = [d for d in sys.path if Path(d or ".").resolve() != here]
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    try:
        runpy.run_module("protorch", run_name="__main__")
    except SystemExit as exc:
        if exc.code not in (None, 0):
            raise
    finally:
        prof.disable()
        prof.dump_stats(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--record",
        metavar="OUT",
        help="profile a run of the app (the arguments: its overrides) into OUT",
    )
    p.add_argument(
        "profiles",
        nargs="+",
        help="cProfile output files of whole runs, or with --record the overrides",
    )
    args = p.parse_args()
    if args.record:
        record(args.record, args.profiles)
        args.profiles = [args.record]
    columns = [part_seconds(pstats.Stats(f)) for f in args.profiles]
    print("| part | " + " | ".join(f"{f}: s (share)" for f in args.profiles) + " |")
    print("|---|" + "---|" * len(columns))
    for label, _ in PARTS:
        cells = []
        for col in columns:
            s, whole = col[label], col["whole run"]
            cells.append("-" if s is None else f"{s:.1f} ({100 * s / whole:.0f} %)")
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
