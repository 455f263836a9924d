"""Every Python block of README.md and docs/library.md runs, in a fresh folder. A block may be run
with a smaller budget: SMALLER lists, per page, the exact text replaced and its replacement, and
each replacement must still find its text (a budget the page changed is noticed, not skipped)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", "docs/library.md"]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)

# (page, block index) -> [(text in the block, what the test runs instead)]
SMALLER = {
    ("README.md", 0): [
        ("num_envs=1000, batch_size=100", "num_envs=10, batch_size=10"),
        ("num_samples=100, max_iter=200))", "num_samples=20, max_iter=5))"),
    ],
    ("docs/library.md", 0): [
        ("num_envs=1000, batch_size=100", "num_envs=10, batch_size=10"),
        (
            "beta=20.0, num_samples=100, max_iter=200, relevance_samples=100",
            "beta=20.0, num_samples=20, max_iter=5, relevance_samples=20",
        ),
        ("progress=True", "progress=False"),
    ],
}


def blocks() -> list[tuple[str, int, str]]:
    found = []
    for page in PAGES:
        for i, m in enumerate(BLOCK.finditer((ROOT / page).read_text())):
            found.append((page, i, m.group(1)))
    return found


def test_the_pages_hold_python_blocks_and_the_replacements_name_real_blocks():
    names = {(p, i) for p, i, _ in blocks()}
    assert ("README.md", 0) in names and len([n for n in names if n[0] == "docs/library.md"]) >= 3
    assert set(SMALLER) <= names


@pytest.mark.parametrize("page, index, code", blocks(), ids=[f"{p}[{i}]" for p, i, _ in blocks()])
def test_a_python_block_runs(page, index, code, tmp_path, monkeypatch, capsys, one_thread):
    for old, new in SMALLER.get((page, index), []):
        assert old in code, f"{page} block {index} no longer holds {old!r}: update SMALLER"
        code = code.replace(old, new)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    torch.manual_seed(0)
    exec(compile(code, f"{page}[{index}]", "exec"), {"__name__": "__snippet__"})
    printed = capsys.readouterr().out
    for claim in re.findall(
        r"print\(.*\)  # (tensor\(True\))", code
    ):  # what a comment says it prints
        assert claim in printed, (
            f"{page} block {index} printed {printed!r}, its comment says {claim}"
        )
