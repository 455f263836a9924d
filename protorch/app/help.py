"""``python -m protorch --help``: the experiments and every config group's choices (``optimizer=``,
``gp=``, ``task=``, ``robot=``, ``tune=``), each with the first sentence of its YAML's header
comment, how to
see and change settings, and what each key means, read from the YAML comments of ``conf/``
(``key: value  # meaning``). Lines are wrapped to the terminal, never cut."""

from __future__ import annotations

import re
import shutil
import textwrap
from pathlib import Path

__all__ = [
    "wants_help",
    "experiment_lines",
    "group_choices",
    "first_sentence",
    "key_meanings",
    "help_text",
    "GROUPS",
]

# the config groups a command line chooses from, in the order the help lists them
GROUPS = (
    ("experiment", "the experiment (sets every group below to its own choices)"),
    ("optimizer", "the loop's optimiser; optimizer.<key>=... changes one setting"),
    ("gp", "the environment map's backend"),
    ("task", "the task (custom: your own class, task._target_=my_module.MyTask)"),
    ("robot", "the arm of experiment=arm_reach (custom: your URDF, docs/your_own_robot.md)"),
    ("tune", "a hyperparameter search preset (with -m)"),
)
_SENTENCE_END = re.compile(
    r"(?<!\bSec)(?<!\bFig)(?<!\be\.g)(?<!\bi\.e)(?<!\bvs)(?<!\bEq)(?<!\bal)\.(?=\s|$)|:$"
)

# Hydra's own informational flags: passed through to Hydra, never answered with our help
HYDRA_FLAGS = ("--hydra-help", "--info", "-i", "--version", "--shell-completion", "-sc")
_KEY = re.compile(
    r"^(?P<indent> *)(?P<key>[A-Za-z_][\w-]*):(?P<value>[^#]*?)\s*(#\s?(?P<meaning>.*))?$"
)
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


def first_sentence(path: Path) -> str:
    """The first sentence of a YAML file's header comment (after ``@package``), whole however many
    lines it spans (abbreviations such as "Sec." and "Fig." do not end it; a trailing colon
    does)."""
    text: list[str] = []
    for line in path.read_text().splitlines():
        m = _COMMENT.match(line)
        if m is None or (text and (not m["text"].strip() or m["text"].startswith(" "))):
            break  # the header ends, or a blank comment line / an indented example follows
        if not m["text"].startswith("@package"):
            text.append(m["text"].strip())
    para = " ".join(text)
    end = _SENTENCE_END.search(para)
    return para if end is None else para[: end.start()] + ("." if end.group() == "." else "")


def experiment_lines(conf: Path) -> dict[str, str]:
    """``{name: the first sentence of conf/experiment/<name>.yaml}``."""
    return group_choices(conf, "experiment")


def group_choices(conf: Path, group: str) -> dict[str, str]:
    """``{choice: the first sentence of conf/<group>/<choice>.yaml}`` of a config group."""
    return {path.stem: first_sentence(path) for path in sorted((conf / group).glob("*.yaml"))}


def _wrap(head: str, text: str, width: int, indent: int) -> list[str]:
    """``head`` then ``text`` wrapped to ``width``, continuation lines indented by ``indent``."""
    first = f"{head}{text}"
    return textwrap.wrap(
        first,
        width=width,
        subsequent_indent=" " * indent,
        break_long_words=False,
        break_on_hyphens=False,
    ) or [head.rstrip()]


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
    return [(r[0], r[1], r[2]) for r in rows]


def _table(rows, width: int, indent: str = "  ", max_key: int = 36) -> list[str]:
    """``key=value  meaning`` rows, the meanings wrapped in a column; a ``key=value`` wider than
    ``max_key`` gets its meaning on the lines below it."""
    col = min(max((len(f"{k}={v}") for k, v, _ in rows), default=0), max_key)
    out = []
    for k, v, m in rows:
        kv = f"{k}={v}"
        if not m:
            out.append(f"{indent}{kv}")
        elif len(kv) > col:
            out.append(f"{indent}{kv}")
            out += _wrap(" " * (len(indent) + col + 2), m, width, len(indent) + col + 2)
        else:
            out += _wrap(f"{indent}{kv.ljust(col)}  ", m, width, len(indent) + col + 2)
    return out


def _choices(conf: Path, width: int) -> list[str]:
    """Every group's choices, ``group=NAME  first sentence``, wrapped."""
    lines = []
    for group, meaning in GROUPS:
        choices = group_choices(conf, group)
        if not choices:
            continue
        lines += ["", f"{group}=NAME: {meaning} (conf/{group}/NAME.yaml)"]
        col = max(map(len, choices))
        for name, text in choices.items():
            lines += _wrap(f"  {name.ljust(col)}  ", text, width, col + 4)
    return lines


def help_text(conf: Path, argv: list[str]) -> str:
    """The help: experiments one line each, how to see / change / sweep settings, the shared
    keys of ``config.yaml`` and, for ``experiment=X --help``, the keys of ``X``'s yaml."""
    names = experiment_lines(conf)
    width = max(60, min(shutil.get_terminal_size((100, 24)).columns, 120) - 1)
    chosen = chosen_experiment(argv)
    lines = [
        "protorch: PRO policy search (Ewerton et al., IROS 2019) and the paper's experiments.",
        "",
        "usage: python -m protorch experiment=NAME [group=CHOICE ...] [key=value ...]",
        *_choices(conf, width),
        "",
        "  python -m protorch experiment=NAME --cfg job      show every setting of NAME (resolved)",
        "  python -m protorch experiment=NAME --help         this help plus what NAME's keys mean",
        "  python -m protorch experiment=NAME key=value ...  change settings, e.g. seed=1 "
        "optimizer.beta=10",
        "  python -m protorch -m experiment=NAME optimizer.beta=1,10,20   a sweep (one run per "
        "value)",
        "  python -m protorch --hydra-help                   Hydra's own options",
        "",
        'Each run writes metrics.json (headline numbers under "summary"), status.json, config.yaml '
        "and",
        "figures into hydra.run.dir (default runs/NAME__SEED__TIME) and prints a summary as its "
        "last lines.",
        "",
        "shared settings (conf/config.yaml):",
        *_table([r for r in key_meanings(conf / "config.yaml") if r[0] != "name"], width),
    ]
    if chosen is not None:
        path = conf / "experiment" / f"{chosen}.yaml"
        if not path.is_file():
            lines += ["", f"unknown experiment {chosen!r}; choose one of {sorted(names)}"]
        else:
            lines += [
                "",
                *_wrap(
                    f"settings of experiment={chosen} ({path.relative_to(conf.parent)}; ",
                    "keys without a comment are listed by --cfg job):",
                    width,
                    2,
                ),
                *_table([r for r in key_meanings(path) if r[2]], width),
            ]
            if "override /robot" in path.read_text():
                lines += [
                    "",
                    *_wrap(
                        "robot settings (conf/robot/custom.yaml; with robot=panda each is null, "
                        "the Panda's ",
                        "own value, and robot.KEY=VALUE changes it): python -m protorch "
                        "experiment=arm_reach robot=custom robot.urdf=my_arm.urdf "
                        "robot.end_link=tool0 "
                        "robot.home=[...]",
                        width,
                        2,
                    ),
                    *_table(
                        [
                            (f"robot.{k}", v, m)
                            for k, v, m in key_meanings(conf / "robot" / "custom.yaml")
                            if m
                        ],
                        width,
                    ),
                ]
    return "\n".join(lines)
