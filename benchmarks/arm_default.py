"""The arm's default run before and after it planned with the volumes, side by side (on demand).

    python benchmarks/arm_default.py [--seeds 0 1 2] [--before-seeds 0] [--together] [--quick]
    [--out FILE] [override ...]

``before``: the default of protorch before the volumes became it, ``experiment=arm_reach
task.collision=skeleton settings.loop.refill=false`` (the skeleton plan, the step loop);
``after``: today's default, ``experiment=arm_reach`` (the volumes, the refill loop). Each run is
a fresh ``python -m protorch`` process into a temporary folder, timed by its wall clock; the runs
of a seed alternate (before, after) so both see the same load. Printed per run: wall seconds,
the loop's and the priors' seconds (``metrics.json``), the kinematic and the MuJoCo held-out and
moving success; then per seed with both runs the wall-time ratio after / before. ``--together``
runs a seed's before and after at the same time, ``threads=1`` each (two cores: both see the same
load, the fairest comparison on a machine that is not idle). ``--out`` writes
the rows as JSON. ``--quick``: a reduced budget (300 environments and priors, 50 held-out, 10
moving episodes), a check that the script works. The machine's load changes absolute times:
compare the rows of one run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEFORE = ["task.collision=skeleton", "settings.loop.refill=false"]
QUICK = [
    "settings.loop.num_envs=300",
    "task.priors=300",
    "settings.test.num_envs=50",
    "settings.dynamic.episodes=10",
]


def start_run(name: str, seed: int, extra: list[str], overrides: list[str]) -> dict:
    """Start ``python -m protorch experiment=arm_reach seed=<seed> <extra> <overrides>`` in a
    temporary folder; :func:`finish_run` waits for it."""
    tmp = tempfile.TemporaryDirectory(prefix=f"arm_default_{name}_")
    cmd = [
        sys.executable,
        "-m",
        "protorch",
        "experiment=arm_reach",
        f"seed={seed}",
        "settings.progress=false",
        "settings.physics.render=false",
        "plot=false",
        f"hydra.run.dir={tmp.name}",
        *extra,
        *overrides,
    ]
    run = {
        "name": name,
        "seed": seed,
        "extra": extra,
        "overrides": overrides,
        "tmp": tmp,
        "cmd": cmd,
        "t0": time.perf_counter(),
    }
    run["proc"] = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )

    def wait():  # the wall clock stops when the process ends, whichever run is waited for first
        run["err"] = run["proc"].communicate()[1]
        run["wall"] = time.perf_counter() - run["t0"]

    run["waiter"] = threading.Thread(target=wait)
    run["waiter"].start()
    return run


def one_run(name: str, seed: int, extra: list[str], overrides: list[str]) -> dict:
    """``python -m protorch experiment=arm_reach seed=<seed> <extra> <overrides>``, timed."""
    return finish_run(start_run(name, seed, extra, overrides))


def finish_run(run: dict) -> dict:
    """Wait for a :func:`start_run` process; its row."""
    name, seed, extra, overrides = run["name"], run["seed"], run["extra"], run["overrides"]
    with run["tmp"] as tmp:
        run["waiter"].join()
        wall, err = run["wall"], run["err"]
        if run["proc"].returncode != 0:
            raise RuntimeError(
                f"{' '.join(run['cmd'])} failed ({run['proc'].returncode}):\n{err[-3000:]}"
            )
        m = json.loads((Path(tmp) / "metrics.json").read_text())
    phys = m.get("physics") or {}
    return {
        "name": name,
        "seed": seed,
        "command": " ".join(
            ["python -m protorch experiment=arm_reach", f"seed={seed}", *extra, *overrides]
        ),
        "wall": round(wall, 1),
        "loop": m["seconds"].get("loop"),
        "priors": m["seconds"].get("priors"),
        "held_out": m["test"]["success_rate"],
        "moving": (m.get("dynamic") or {}).get("success_rate"),
        "physics_held_out": (phys.get("test") or {}).get("success_rate"),
        "physics_moving": (phys.get("dynamic") or {}).get("success_rate"),
        "rollouts": (m.get("loop") or {}).get("rollouts"),
    }


def show(r: dict) -> None:
    f = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
    print(
        f"{r['name']:6} seed {r['seed']}: wall {r['wall']:7.1f} s (loop {r['loop']} s, priors "
        f"{r['priors']} s)  "
        f"kinematic {f(r['held_out'])} / {f(r['moving'])}  MuJoCo {f(r['physics_held_out'])} / "
        f"{f(r['physics_moving'])}",
        flush=True,
    )


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds of the default (after) run"
    )
    p.add_argument(
        "--before-seeds",
        type=int,
        nargs="*",
        default=[0],
        help="seeds also run as before, for the ratio",
    )
    p.add_argument(
        "--quick", action="store_true", help="a reduced budget (a check that the script works)"
    )
    p.add_argument(
        "--together", action="store_true", help="a seed's before and after at once, threads=1 each"
    )
    p.add_argument("--out", type=Path, help="write the rows as JSON")
    p.add_argument("overrides", nargs="*", help="more Hydra overrides for both")
    a = p.parse_args(argv)
    overrides = (QUICK if a.quick else []) + list(a.overrides)
    rows = []
    for seed in a.seeds:
        runs = ([("before", BEFORE)] if seed in a.before_seeds else []) + [("after", [])]
        if a.together:
            started = [
                start_run(name, seed, extra, overrides + ["threads=1"]) for name, extra in runs
            ]
            done = [finish_run(r) for r in started]
        else:
            done = [one_run(name, seed, extra, overrides) for name, extra in runs]
        for row in done:
            rows.append(row)
            show(row)
            if a.out:
                a.out.write_text(json.dumps(rows, indent=1))
        pair = {r["name"]: r for r in rows if r["seed"] == seed}
        if len(pair) == 2:
            print(
                f"seed {seed}: wall after / before = "
                f"{pair['after']['wall'] / pair['before']['wall']:.2f}x",
                flush=True,
            )
    return rows


if __name__ == "__main__":
    main()
