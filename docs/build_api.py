"""Build the API reference from the docstrings: ``pip install -e ".[docs]" && python
docs/build_api.py`` writes HTML into ``site/`` (``--out DIR`` elsewhere; ``--modules a b`` a subset).

The reference covers the library (what a user imports), each package's public names (its
``__all__``); the Hydra app, the viewer and the experiments' internals are left out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# the library's packages, in reading order; tests/test_api_docs.py checks none is missing
MODULES = [
    "protorch", "protorch.primitives", "protorch.optim", "protorch.gp", "protorch.loop",
    "protorch.tasks", "protorch.robots", "protorch.data", "protorch.control", "protorch.policy", "protorch.sim",
    "protorch.figures", "protorch.errors", "protorch.checks", "protorch.threads",
]


def build(out: Path, modules: list[str]) -> list[Path]:
    """Write the HTML of ``modules`` into ``out``; returns the pages written."""
    import pdoc
    import pdoc.render

    pdoc.render.configure(docformat="restructuredtext", search=True, show_source=False)
    pdoc.pdoc(*modules, output_directory=out)
    return sorted(out.rglob("*.html"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("site"), help="output folder (default: site)")
    ap.add_argument("--modules", nargs="+", default=MODULES, help="modules to document (default: the library)")
    args = ap.parse_args(argv)
    pages = build(args.out, args.modules)
    print(f"{len(pages)} pages in {args.out}/ (open {args.out / 'index.html'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
