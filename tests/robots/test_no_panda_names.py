"""Every layer reads the robot description: no module of the package outside ``protorch/robots/``
names the Panda's links, joints or constants (a grep over the package's source)."""

from __future__ import annotations

import re
from pathlib import Path

import protorch

PACKAGE = Path(protorch.__file__).resolve().parent
# a Panda link / joint name ("panda_link5", "panda_hand_tcp", "panda_joint1"), a PANDA_* constant,
# or
# an import of a Panda module
PANDA = re.compile(r"panda_(link|hand|joint|finger)|PANDA_|robots\.panda\b|import panda\b")


def offending_lines(root: Path = PACKAGE) -> list[str]:
    out = []
    for path in sorted(root.rglob("*.py")):
        if path.is_relative_to(root / "robots"):
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if PANDA.search(line):
                out.append(f"{path.relative_to(root.parent)}:{n}: {line.strip()}")
    return out


def test_no_module_outside_robots_names_the_pandas_links(tmp_path):
    assert offending_lines() == []
    # the check itself finds what it is for (a module naming a Panda link, outside robots/)
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "ok.py").write_text('END = "panda_hand_tcp"\n')
    (tmp_path / "scene.py").write_text('hand = spec.body("panda_hand")\n')
    assert offending_lines(tmp_path) == [
        f'{tmp_path.name}/scene.py:1: hand = spec.body("panda_hand")'
    ]
