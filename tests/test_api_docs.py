"""The API reference builds from the docstrings with one command (docs/build_api.py, pdoc): a
subset here, quickly; the module list covers every package of the library."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs"))
import build_api  # noqa: E402

# the app, the experiments and the viewer are edges, not the library a user imports
EDGES = {"app", "experiments", "view"}


def test_every_library_package_is_in_the_reference():
    packages = {p.name for p in (ROOT / "protorch").iterdir() if p.is_dir() and any(p.glob("*.py"))}
    missing = sorted(
        f"protorch.{p}" for p in packages - EDGES if f"protorch.{p}" not in build_api.MODULES
    )
    assert not missing, f"docs/build_api.py's MODULES lacks {missing}"
    unknown = [m for m in build_api.MODULES if importlib.util.find_spec(m) is None]
    assert not unknown, f"MODULES names modules that do not exist: {unknown}"


@pytest.mark.skipif(
    importlib.util.find_spec("pdoc") is None, reason='pdoc not installed: pip install -e ".[docs]"'
)
def test_the_reference_builds_and_holds_the_docstrings(tmp_path):
    pages = build_api.build(tmp_path, ["protorch.errors", "protorch.primitives"])
    names = {p.relative_to(tmp_path).as_posix() for p in pages}
    assert {
        "protorch/errors.html",
        "protorch/primitives.html",
        "protorch/primitives/promp.html",
    } <= names
    errors = (tmp_path / "protorch" / "errors.html").read_text()
    assert "ProtorchError" in errors and "keeps its builtin base" in errors
    assert (
        'href="#ProMP.trajectory"'
        in (tmp_path / "protorch" / "primitives" / "promp.html").read_text()
    )
