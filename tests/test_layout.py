"""The package's layout limits, checked by parsing the source (no import of protorch needed).

- no import cycle between protorch's modules, and no protorch import inside a function (such an
  import is how a cycle is usually hidden, so it counts as one);
- no module over 700 lines, no function over 120 lines (its docstring excluded), as ruff format
  lays them out: hard ceilings. 400 lines a module is a prompt in review (``python
  tests/test_layout.py`` lists the modules past it), not a target to meet with long lines;
- no private name (``_x``) imported from another module;
- no project history in docstrings.

Run ``python tests/test_layout.py`` for the full list of violations.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "protorch"
MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 120
REVIEW_MODULE_LINES = 400
# functions past the ceiling once ruff format laid them out one argument a line: to split
LONG_FUNCTIONS_TO_SPLIT = {"protorch.loop._improve"}
HISTORY = re.compile(
    r"\b(teammate|as before|previously|used to|no longer|was changed|this session)\b", re.I
)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        out[module_name(path)] = (path, ast.parse(path.read_text(), filename=str(path)))
    return out


def resolve(current: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = current.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(mods) -> list[tuple[str, str, str, int, bool]]:
    """Every protorch import: (importer, imported module, name or '', line, inside a function)."""
    found = []
    for name, (path, tree) in mods.items():
        is_pkg = path.name == "__init__.py"
        funcs = [
            n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
        ]
        inner = {id(n) for f in funcs for n in ast.walk(f) if n is not f}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.split(".")[0] == "protorch":
                        found.append((name, a.name, "", node.lineno, id(node) in inner))
            elif isinstance(node, ast.ImportFrom):
                target = resolve(name, is_pkg, node)
                if target.split(".")[0] != "protorch":
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in mods:  # ``from . import module``
                        found.append((name, sub, "", node.lineno, id(node) in inner))
                    else:
                        found.append((name, target, a.name, node.lineno, id(node) in inner))
    return found


def cycles(mods, edges) -> list[list[str]]:
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for src, dst, _, _, _ in edges:
        if dst in graph and dst != src:
            graph[src].add(dst)
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            strong(v)
    return out


def function_lengths(tree: ast.Module):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(getattr(body[0], "value", None), ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                body = body[1:]
            if not body:
                continue
            first = min([body[0].lineno] + [d.lineno for d in node.decorator_list])
            yield node.name, node.lineno, body[-1].end_lineno - first + 1


def violations() -> dict[str, list[str]]:
    mods = modules()
    edges = imports(mods)
    out = {
        "cycles": [" -> ".join(c) for c in cycles(mods, edges)],
        "inner_imports": [f"{s}:{line} imports {d}" for s, d, _, line, inner in edges if inner],
        "private_imports": [
            f"{s}:{line} imports {d}.{n}"
            for s, d, n, line, _ in edges
            if n.startswith("_") and d != s
        ],
        "long_modules": [],
        "long_functions": [],
        "history": [],
    }
    for name, (path, tree) in mods.items():
        n = len(path.read_text().splitlines())
        if n > MAX_MODULE_LINES:
            out["long_modules"].append(f"{name}: {n} lines")
        for fn, line, length in function_lengths(tree):
            if length > MAX_FUNCTION_LINES and f"{name}.{fn}" not in LONG_FUNCTIONS_TO_SPLIT:
                out["long_functions"].append(f"{name}:{line} {fn}: {length} lines")
        for node in ast.walk(tree):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node) or ""
                if HISTORY.search(doc):
                    out["history"].append(
                        f"{name}:{getattr(node, 'lineno', 1)}: {HISTORY.search(doc).group(0)!r}"
                    )
    return out


def _check(kind: str) -> None:
    found = violations()[kind]
    assert not found, f"{kind}:\n  " + "\n  ".join(found)


def test_no_import_cycles():
    _check("cycles")


def test_no_protorch_imports_inside_functions():
    _check("inner_imports")


def test_no_private_names_imported_across_modules():
    _check("private_imports")


def test_modules_at_most_700_lines():
    _check("long_modules")


def test_functions_at_most_120_lines():
    _check("long_functions")


def test_no_project_history_in_docstrings():
    _check("history")


def test_the_checker_finds_a_cycle_and_a_long_function(tmp_path):
    """The checker itself: a two-module cycle and a too-long function are found."""
    tree_a = ast.parse("from protorch.b import x\n")
    too_long = MAX_FUNCTION_LINES + 1
    tree_b = ast.parse("from .a import y\n" + "def f():\n" + "    z = 1\n" * too_long)
    mods = {"protorch.a": (PACKAGE / "a.py", tree_a), "protorch.b": (PACKAGE / "b.py", tree_b)}
    assert cycles(mods, imports(mods)) == [["protorch.a", "protorch.b"]]
    assert [length for _, _, length in function_lengths(tree_b)] == [too_long]


if __name__ == "__main__":
    total = 0
    for kind, items in violations().items():
        print(f"{kind}: {len(items)}")
        for item in items:
            print(f"  {item}")
        total += len(items)
    review = [(len(p.read_text().splitlines()), n) for n, (p, _) in modules().items()]
    review = sorted((r for r in review if r[0] > REVIEW_MODULE_LINES), reverse=True)
    print(f"modules past {REVIEW_MODULE_LINES} lines (to split when next touched): {len(review)}")
    for n, name in review:
        print(f"  {name}: {n}")
    sys.exit(1 if total else 0)
