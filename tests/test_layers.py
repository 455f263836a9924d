"""Layers point down: the library core imports neither Hydra, OmegaConf nor the experiments, the
app or the viewer (at import, checked in a fresh process, and in its source, checked by reading
it); ``protorch`` exports every optimiser; protorch's exceptions share one base."""

from __future__ import annotations

import ast
import builtins
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ("primitives", "optim", "gp", "robots", "tasks", "data", "loop", "policy", "control", "sim")
ABOVE = ("protorch.experiments", "protorch.app", "protorch.view", "hydra", "omegaconf")
# none: protorch.load's fallback for a run folder written before policy.json imports the
# experiments by name (importlib), inside the function that needs it
ALLOWED: set[tuple[str, str]] = set()

IMPORTS = textwrap.dedent("""
    import importlib, sys
    above = tuple(sys.argv[1].split(","))
    def loaded():
        return {m for m in sys.modules if m == above or m.startswith(above)}
    import protorch
    print("protorch", sorted(loaded()))
    for name in sys.argv[2].split(","):
        importlib.import_module("protorch." + name)
        print(name, sorted(loaded()))
""")


def test_importing_the_core_imports_nothing_above_it():
    """``import protorch`` and each core package, in one fresh process: no module of
    :data:`ABOVE` (nor any submodule of one) is in ``sys.modules`` after any of them."""
    out = subprocess.run(
        [sys.executable, "-c", IMPORTS, ",".join(ABOVE), ",".join(CORE)],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.split("\n")
    assert lines[0] == "protorch []", lines[0]
    assert lines[1 : 1 + len(CORE)] == [f"{name} []" for name in CORE]


def _imported(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; relative imports resolved)."""
    rel = path.relative_to(ROOT).with_suffix("")
    package = list(rel.parts[:-1]) if rel.name != "__init__" else list(rel.parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join([*base, node.module] if node.module else base)
            out.add(mod)
            out |= {f"{mod}.{a.name}" for a in node.names}
    return out


def test_the_cores_source_imports_nothing_above_it():
    """No module of a core package imports the app, the viewer, the experiments, Hydra or
    OmegaConf, not even inside a function, but for protorch.load's documented fallback."""
    found = []
    for pkg in CORE:
        for path in sorted((ROOT / "protorch" / pkg).rglob("*.py")):
            where = str(path.relative_to(ROOT))
            allowed = tuple(m for w, m in ALLOWED if w == where)
            for mod in sorted(_imported(path)):
                above = mod in ABOVE or mod.startswith(tuple(a + "." for a in ABOVE))
                if above and not (
                    mod in allowed or mod.startswith(tuple(a + "." for a in allowed))
                ):
                    found.append(f"{where} imports {mod}")
    assert not found, found


def test_protorch_exports_every_optimiser():
    import protorch
    from protorch.optim import OPTIMIZERS

    for cls in set(OPTIMIZERS.values()):
        assert getattr(protorch, cls.__name__) is cls, cls.__name__
        assert cls.__name__ in protorch.__all__
    assert {"PRO", "EPRO", "RWR", "RWPO", "CEM", "CMAES"} <= set(protorch.__all__)


def test_every_protorch_exception_subclasses_protorch_error():
    """Every exception class defined in protorch/ derives from :class:`ProtorchError` (and keeps
    its builtin base)."""
    import importlib

    from protorch.errors import ProtorchError

    errors = {
        n
        for n in dir(builtins)
        if isinstance(getattr(builtins, n), type)
        and issubclass(getattr(builtins, n), Exception)
        and not issubclass(getattr(builtins, n), Warning)
    } | {"ProtorchError"}
    found = []
    for path in sorted((ROOT / "protorch").rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef) and any(
                isinstance(b, ast.Name) and b.id in errors for b in node.bases
            ):
                found.append((path, node.name))
    assert len(found) >= 7, found
    for path, name in found:
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        if module == "protorch.errors":
            continue
        cls = getattr(importlib.import_module(module), name)
        assert issubclass(cls, ProtorchError), f"{module}.{name}"
