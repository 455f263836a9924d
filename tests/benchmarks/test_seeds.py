"""benchmarks/seeds.py with the app's runs faked (each "run" writes the metrics a seed gives): the
seed check runs the experiment itself (not an experiment named after its folder), its verdict
follows the widened range, and the tables land in seeds.md."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from protorch.app import report as rep
from tests.app.test_report import make_run
from tests.app.test_spread import headline

from . import benchmark_module

HELD_OUT = {
    0: 0.99,
    1: 0.97,
    2: 1.0,
    3: 0.985,
    4: 0.995,
    11: 0.966,
}  # seed 11: inside [0.965, 1.005]


@pytest.fixture
def bench():
    with benchmark_module("seeds.py", "seeds_bench") as mod:
        yield mod


def fake_app(held_out: dict, commands: list):
    """A stand-in for ``subprocess.run``: the app's multirun writes one run per seed, the report
    runs
    here, anything else (git, uname: the provenance line) runs as it is."""
    real = subprocess.run

    def run(cmd, cwd=None, check=False, **kwargs):
        if cmd[0] != sys.executable:
            return real(cmd, cwd=cwd, check=check, **kwargs)
        commands.append(cmd)
        args = dict(a.split("=", 1) for a in cmd[3:] if "=" in a)
        if cmd[1:3] == ["-m", "protorch"]:
            for i, seed in enumerate(int(s) for s in args["seed"].split(",")):
                make_run(
                    Path(args["hydra.sweep.dir"]),
                    str(i),
                    [f"experiment={args['experiment']}", f"seed={seed}"],
                    {"name": args["experiment"], "seed": seed},
                    headline(held_out[seed], 0.95),
                )
        else:
            assert cmd[1:3] == ["-m", "protorch.app.report"] and rep.main(cmd[3:]) == 0

    return run


@pytest.mark.parametrize("seed11, status", [(0.966, 0), (0.96, 1)])
def test_the_seed_check_runs_the_experiment_and_says_whether_it_lies_in_the_range(
    bench, tmp_path, monkeypatch, seed11, status
):
    commands = []
    monkeypatch.setattr(bench.subprocess, "run", fake_app({**HELD_OUT, 11: seed11}, commands))
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "seeds.py",
            "--experiments",
            "point_particle",
            "--check-seed",
            "11",
            "--out",
            str(tmp_path),
        ],
    )
    assert bench.main() == status
    runs = [shlex.join(c) for c in commands if c[1:3] == ["-m", "protorch"]]
    assert len(runs) == 2 and all("experiment=point_particle " in c for c in runs)
    assert (
        "seed=11 " in runs[1] and f"hydra.sweep.dir={tmp_path / 'point_particle_seed11'}" in runs[1]
    )
    text = (tmp_path / "seeds.md").read_text()
    assert (
        "| held-out success | PRO loop | `test.success_rate` | 0.988 | 0.970 - 1.000 | 0.990 |"
        in text
    )
    verdict = next(line for line in text.splitlines() if line.startswith("seed 11:"))
    assert ("outside [0.965, 1.005]" in verdict) == bool(status), verdict
