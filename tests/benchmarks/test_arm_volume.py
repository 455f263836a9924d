"""benchmarks/arm_volume.py at its quick sizes: every row runs, the pruned gap, the success
verdicts and the check in pieces equal the other paths bit for bit, the placed capsules, the
Jacobian and the detour IK to round-off."""

from __future__ import annotations

import re

import pytest

from tests.benchmarks import benchmark_module


@pytest.mark.slow
def test_the_volume_pieces_agree_with_what_they_replace(capsys):
    with benchmark_module("arm_volume.py", "_arm_volume") as bench:
        bench.main(["--quick", "--repeats", "1"])
    rows = [line for line in capsys.readouterr().out.splitlines() if "largest difference" in line]
    assert len(rows) == 6
    worst = {
        line.split("  ")[0].strip(): float(re.search(r"largest difference (\S+)", line).group(1))
        for line in rows
    }
    by = lambda key: next(v for k, v in worst.items() if k.startswith(key))  # noqa: E731
    assert (
        by("their gap") == 0.0
        and by("the volume success check") == 0.0
        and by("volume gap and table") == 0.0
    )
    assert by("capsules placed") < 1e-12 and by("Jacobian") < 1e-12 and by("detour IK") < 1e-9
