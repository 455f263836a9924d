"""``python -m protorch --help``: the experiments, how to see and change their settings, and what
each key means, read from the YAML comments of ``conf/`` (``key: value  # meaning``)."""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["wants_help", "experiment_lines", "key_meanings", "help_text"]

# Hydra's own informational flags: passed through to Hydra, never answered with our help
HYDRA_FLAGS = ("--hydra-help", "--info", "-i", "--version", "--shell-completion", "-sc")
_KEY = re.compile(r"^(?P<indent> *)(?P<key>[A-Za-z_][\w-]*):(?P<value>[^#]*?)\s*(#\s?(?P<meaning>.*))?$")
_COMMENT = re.compile(r"^(?P<indent> *)#\s?(?P<text>.*)$")


def chosen_experiment(argv: list[str]) -> str | None:
    """The ``experiment=NAME`` (or ``+experiment=``) of a command line, else ``None``."""
    for arg in argv:
        key, sep, value = arg.lstrip("+").partition("=")
        if sep and key == "experiment" and value not in ("", "null"):
            return value
    return None


def wants_help(argv: list[str]) -> bool:
    """``--help`` / ``-h``, or a command line that names no experiment (a bare ``python -m
    protorch``); Hydra's own flags (``--hydra-help``, ``--info``, ...) are left to Hydra."""
    if any(a.split("=")[0] in HYDRA_FLAGS for a in argv):
        return False
    return "--help" in argv or "-h" in argv or chosen_experiment(argv) is None


def experiment_lines(conf: Path) -> dict[str, str]:
    """``{name: the first comment line of conf/experiment/<name>.yaml}`` (after ``@package``)."""
    out = {}
    for path in sorted((conf / "experiment").glob("*.yaml")):
        first = ""
        for line in path.read_text().splitlines():
            m = _COMMENT.match(line)
            if m is None:
                break
            if not m["text"].startswith("@package"):
                first = m["text"].strip()
                break
        out[path.stem] = first
    return out


def key_meanings(path: Path) -> list[tuple[str, str, str]]:
    """``(dotted key, value, meaning)`` for each ``key: value  # meaning`` line of a YAML file;
    a comment-only line indented under it continues the meaning. Nested keys are dotted by their
    indentation (``settings.loop.num_envs``); ``hydra:`` and ``defaults:`` are skipped."""
    rows: list[list[str]] = []
    stack: list[tuple[int, str]] = []
    last_indent = None
    for line in path.read_text().splitlines():
        m = _KEY.match(line)
        if m is None:
            c = _COMMENT.match(line)
            if c and rows and last_indent is not None and len(c["indent"]) > last_indent:
                rows[-1][2] = f"{rows[-1][2]} {c['text'].strip()}".strip()
            elif not line.strip().startswith("- "):
                last_indent = None
            continue
        indent = len(m["indent"])
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, m["key"]))
        dotted = ".".join(k for _, k in stack)
        if stack[0][1] in ("hydra", "defaults"):
            last_indent = None
            continue
        meaning = (m["meaning"] or "").strip()
        if meaning or m["value"].strip():
            rows.append([dotted, m["value"].strip(), meaning])
            last_indent = indent if meaning else None
    return [tuple(r) for r in rows]


def _table(rows, indent="  ") -> list[str]:
    width = max((len(f"{k}={v}") for k, v, _ in rows), default=0)
    return [f"{indent}{f'{k}={v}'.ljust(width)}  {m}".rstrip() for k, v, m in rows]


def help_text(conf: Path, argv: list[str]) -> str:
    """The help: experiments one line each, how to see / change / sweep settings, the shared
    keys of ``config.yaml`` and, for ``experiment=X --help``, the keys of ``X``'s yaml."""
    names = experiment_lines(conf)
    width = max(map(len, names), default=0)
    chosen = chosen_experiment(argv)
    lines = [
        "protorch: PRO policy search (Ewerton et al., IROS 2019) and the paper's experiments.",
        "",
        "usage: python -m protorch experiment=NAME [key=value ...]",
        "",
        "experiments (conf/experiment/NAME.yaml):",
        *(f"  {n.ljust(width)}  {t}" for n, t in names.items()),
        "",
        "  python -m protorch experiment=NAME --cfg job      show every setting of NAME (resolved)",
        "  python -m protorch experiment=NAME --help         this help plus what NAME's keys mean",
        "  python -m protorch experiment=NAME key=value ...  change settings, e.g. seed=1 optimizer.beta=10",
        "  python -m protorch -m experiment=NAME optimizer.beta=1,10,20   a sweep (one run per value)",
        "  python -m protorch --hydra-help                   Hydra's own options",
        "",
        "Each run writes metrics.json (headline numbers under \"summary\"), status.json, config.yaml and",
        "figures into hydra.run.dir (default runs/NAME__SEED__TIME) and prints a summary as its last lines.",
        "",
        "shared settings (conf/config.yaml):",
        *_table([r for r in key_meanings(conf / "config.yaml") if r[0] != "name"]),
    ]
    if chosen is not None:
        path = conf / "experiment" / f"{chosen}.yaml"
        if not path.is_file():
            lines += ["", f"unknown experiment {chosen!r}; choose one of {sorted(names)}"]
        else:
            lines += ["", f"settings of experiment={chosen} ({path.relative_to(conf.parent)}; "
                      "keys without a comment are listed by --cfg job):",
                      *_table([r for r in key_meanings(path) if r[2]])]
    return "\n".join(lines)
