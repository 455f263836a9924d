"""The docs' tables of measurements and what regenerates them (``tests/test_docs.py``).

Convention: the last non-blank line above every table in ``docs/`` is an HTML comment, invisible
on the rendered page, of one of two kinds::

    <!-- measured: commit=9e99b1a command="python -m protorch experiment=point_particle threads=1"
         keys="test.success_rate dynamic.success_rate" -->
    <!-- not measured -->

``commit`` is the commit whose code gave the numbers; ``command`` (one or more) what regenerates
them: ``python -m protorch ...`` (its overrides must compose with the app's Hydra config and pass
:func:`protorch.experiments.check_config`), ``python benchmarks/<script>.py ...`` or ``python -m
<module> ...`` (the file must exist and every ``--flag`` be one its ``argparse`` declares);
``keys`` the metrics keys the table quotes, each one a key that experiment's ``metrics.json``
holds (:data:`KEYS_FILE`, recorded from real runs: ``python -m tests.docs_tables --record
RUN_DIR ...``). A sweep's ``a,b,c`` is checked at its first value; ``hydra.*`` overrides are
Hydra's own. Nothing is re-run: the check is that the page and the code speak of the same things.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import re
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
KEYS_FILE = Path(__file__).with_name("docs_metric_keys.json")
COMMENT = re.compile(r"^<!--\s*(measured:|not measured)(.*?)-->\s*$", re.S)
COMMIT = re.compile(r"^[0-9a-f]{7,40}$")
SEPARATOR = re.compile(r"^\|\s*:?-{3,}")


@dataclass
class Table:
    page: Path
    line: int  # 1-based line of the table's header
    kind: str | None  # "measured", "not measured", or None: no comment above it
    commit: str | None = None
    commands: list[str] = field(default_factory=list)
    keys: list[str] = field(default_factory=list)
    error: str | None = None  # a malformed comment

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def _comment_above(lines: list[str], i: int) -> str | None:
    """The HTML comment ending on the last non-blank line above line ``i`` (0-based), joined."""
    j = i - 1
    while j >= 0 and not lines[j].strip():
        j -= 1
    if j < 0 or not lines[j].rstrip().endswith("-->"):
        return None
    k = j
    while k >= 0 and "<!--" not in lines[k]:
        k -= 1
    return " ".join(line.strip() for line in lines[k : j + 1]) if k >= 0 else None


def tables(page: Path) -> list[Table]:
    """Every table of ``page`` with what its comment says."""
    lines, out = page.read_text().splitlines(), []
    for i, line in enumerate(lines[:-1]):
        if not (line.startswith("|") and SEPARATOR.match(lines[i + 1])):
            continue
        text = _comment_above(lines, i)
        m = COMMENT.match(text) if text else None
        if m is None:
            out.append(Table(page, i + 1, None))
            continue
        if m.group(1) == "not measured":
            out.append(Table(page, i + 1, "not measured"))
            continue
        t = Table(page, i + 1, "measured")
        try:
            for item in shlex.split(m.group(2)):
                key, _, value = item.partition("=")
                if key == "commit":
                    t.commit = value
                elif key == "command":
                    t.commands.append(value)
                elif key == "keys":
                    t.keys += value.split()
                else:
                    raise ValueError(f"unknown entry {key!r}")
        except ValueError as exc:
            t.error = str(exc)
        out.append(t)
    return out


# ----------------------------------------------------------------------------- commands
def _flags_of(path: Path, seen: set[Path] | None = None) -> set[str]:
    """The ``--flags`` ``path``'s ``add_argument`` calls declare, and those of the sibling modules
    it imports."""
    seen = set() if seen is None else seen
    if path in seen or not path.is_file():
        return set()
    seen.add(path)
    tree, flags = ast.parse(path.read_text()), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "add_argument":
            flags |= {
                a.value
                for a in node.args
                if isinstance(a, ast.Constant)
                and isinstance(a.value, str)
                and a.value.startswith("-")
            }
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = (
                [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else [a.name for a in node.names]
            )
            for name in names:
                flags |= _flags_of(path.parent / f"{name.split('.')[-1]}.py", seen)
    return flags


def _check_flags(path: Path, args: list[str]) -> str | None:
    flags = _flags_of(path)
    for a in args:
        if a.startswith("--") and a.split("=", 1)[0] not in flags:
            return f"{path.relative_to(ROOT)} declares no {a.split('=', 1)[0]}"
    return None


def _first_of_sweep(override: str) -> str:
    key, _, value = override.partition("=")
    if "," in value and not value.startswith(("[", "{", "'", '"')):
        value = value.split(",", 1)[0]
    return f"{key}={value}"


def app_config(overrides: list[str]) -> dict:
    """The app's resolved config for ``overrides`` (Hydra's compose; a bad override raises)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from protorch.app.main import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        return OmegaConf.to_container(compose("config", overrides=overrides), resolve=True)


def _pybullet_data(word: str) -> str:
    """``robot.urdf=PYBULLET_DATA/xarm/...``: the file in pybullet's data folder where pybullet is
    installed (the ``arms`` extra), else the example arm in ``examples/`` (a URDF of the same
    kind), so that every other override of the command is still checked."""
    if "PYBULLET_DATA/" not in word:
        return word
    key, _, rest = word.partition("PYBULLET_DATA/")
    spec = importlib.util.find_spec("pybullet_data")
    if spec is not None and spec.submodule_search_locations:
        path = Path(list(spec.submodule_search_locations)[0]) / rest
        if path.is_file():
            return key + str(path)
    return key + str(ROOT / "examples" / "my_arm.urdf")


def check_command(command: str) -> tuple[str | None, str | None]:
    """``(error or None, experiment name or None)`` for one table command (module docstring)."""
    words = shlex.split(command)
    while words and re.match(r"^[A-Z_][A-Z0-9_]*=", words[0]):  # MKL_CBWR=AVX2 python ...
        words.pop(0)
    if len(words) < 2 or not words[0].startswith("python"):
        return f"{command!r}: not a python command", None
    if words[1] != "-m":
        script = ROOT / words[1]
        if not script.is_file():
            return f"{command!r}: {words[1]} does not exist", None
        return _check_flags(script, words[2:]), None
    module = words[2]
    if module != "protorch" or (len(words) > 3 and words[3] == "view"):
        spec = importlib.util.find_spec(module)
        if spec is None or spec.origin is None:
            return f"{command!r}: no module {module}", None
        origin = Path(spec.origin)
        main = origin.with_name("__main__.py") if origin.name == "__init__.py" else origin
        return _check_flags(main, [w for w in words[3:] if w.startswith("--")]), None
    overrides = [
        _first_of_sweep(_pybullet_data(w))
        for w in words[3:]
        if w not in ("-m", "--multirun") and not w.startswith(("hydra.", "hydra/", "+hydra."))
    ]
    try:
        cfg = app_config(overrides)
        from protorch.experiments import check_config

        check_config(cfg)
    except Exception as exc:  # noqa: BLE001 - any refusal is the finding
        return f"{command!r}: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}", None
    return None, cfg["name"]


# ----------------------------------------------------------------------------- metric keys
def recorded_keys() -> dict[str, list[str]]:
    return json.loads(KEYS_FILE.read_text()) if KEYS_FILE.is_file() else {}


def record(run_dirs: list[str]) -> dict[str, list[str]]:
    """Add the flattened metrics keys of each run folder's ``metrics.json`` (and of its sweep's
    runs) to :data:`KEYS_FILE`, under the run's experiment."""
    from protorch.experiments.common import flatten_metrics

    keys = {k: set(v) for k, v in recorded_keys().items()}
    for d in run_dirs:
        for path in sorted(Path(d).rglob("metrics.json")):
            if "baselines" in path.relative_to(d).parts:
                continue
            metrics = json.loads(path.read_text())
            flat = flatten_metrics(
                {k: v for k, v in metrics.items() if k not in ("summary", "run")}
            )
            keys.setdefault(metrics["experiment"], set()).update(flat)
    out = {k: sorted(v) for k, v in sorted(keys.items())}
    KEYS_FILE.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    if sys.argv[1:2] != ["--record"] or len(sys.argv) < 3:
        sys.exit("usage: python -m tests.docs_tables --record RUN_DIR [RUN_DIR ...]")
    print({k: len(v) for k, v in record(sys.argv[2:]).items()})
