"""The docs' tables cannot go stale silently (the convention: tests/docs_tables.py): every table
says whether it holds measurements; a measured one names the commit its numbers came from, a
command that still exists (overrides Hydra and the settings' checks accept, a script and flags
that are still there) and metrics keys the command's experiment still writes. Nothing is re-run."""

from __future__ import annotations

import re
import subprocess

import pytest

from protorch.experiments.summary import HEADLINES
from tests.docs_tables import COMMIT, DOCS, ROOT, Table, check_command, recorded_keys, tables

# pages whose tables are not yet annotated (each one's tables still to be given a comment)
PENDING = {
    "benchmarks_main_job.md",
    "benchmarks_optim.md",
    "benchmarks_gp_sparse.md",
    "benchmarks_arm.md",
    "peers.md",
    "peers_variance.md",
}
PAGES = sorted(p for p in DOCS.rglob("*.md") if p.name not in PENDING)
MEASURED = [t for p in PAGES for t in tables(p) if t.kind == "measured"]


def _git(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def test_every_table_says_whether_it_holds_measurements():
    bare = [t.where() for p in PAGES for t in tables(p) if t.kind is None]
    assert not bare, (
        "tables without a <!-- measured: ... --> or <!-- not measured --> comment: "
        + ", ".join(bare)
    )
    assert MEASURED, "no measured table found: the convention is not applied"


@pytest.mark.parametrize("table", MEASURED, ids=Table.where)
def test_a_measured_table_names_its_commit_command_and_keys(table):
    assert table.error is None, f"{table.where()}: {table.error}"
    assert table.commit and COMMIT.match(table.commit), (
        f"{table.where()}: commit={table.commit!r} is not a hash"
    )
    assert table.commands, f"{table.where()}: no command="
    names = set()
    for command in table.commands:
        error, name = check_command(command)
        assert error is None, f"{table.where()}: {error}"
        names.add(name)
    if table.keys:
        known = recorded_keys()
        experiments = names - {None}
        assert experiments, f"{table.where()}: keys= needs a python -m protorch command"
        for name in experiments:
            assert name in known, (
                f"{table.where()}: no recorded metrics keys for {name} "
                "(tests/docs_metric_keys.json)"
            )
            missing = [k for k in table.keys if k not in known[name]]
            assert not missing, f"{table.where()}: {name}'s metrics hold no {', '.join(missing)}"


def test_the_named_commits_exist_where_the_history_is_here():
    if (
        _git("rev-parse", "--git-dir").returncode != 0
        or _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true"
    ):
        pytest.skip("no full git history in this checkout")
    unknown = sorted(
        {
            f"{t.where()}: {t.commit}"
            for t in MEASURED
            if t.commit and _git("cat-file", "-e", f"{t.commit}^{{commit}}").returncode != 0
        }
    )
    assert not unknown, "commits not in this repository: " + ", ".join(unknown)


def test_the_recorded_keys_hold_every_headline_of_the_experiments_they_cover():
    """The record comes from real runs; a headline key the code renamed is missing from it."""
    for name, keys in recorded_keys().items():
        missing = [row.key for row in HEADLINES.get(name, []) if row.key not in keys]
        assert not missing, (
            f"{name}: headline keys {missing} are not in the recorded metrics; record a fresh run"
        )


def test_the_checks_catch_what_went_stale(tmp_path):
    assert check_command("python -m protorch experiment=point_particle threads=1")[0] is None
    assert (
        check_command(
            "MKL_CBWR=AVX2 python -m protorch -m experiment=fig4_window seed=0,1 hydra.sweep.dir=x"
        )[0]
        is None
    )
    assert (
        "no_such_key"
        in check_command("python -m protorch experiment=point_particle settings.no_such_key=1")[0]
    )
    assert "experiment" in check_command("python -m protorch experiment=no_such_experiment")[0]
    assert check_command("python benchmarks/studies/reproducibility.py --ops")[0] is None
    assert (
        "--no-such-flag"
        in check_command("python benchmarks/studies/reproducibility.py --no-such-flag")[0]
    )
    assert "does not exist" in check_command("python benchmarks/no_such_script.py")[0]
    assert check_command("python -m protorch.app.report runs/x --spread")[0] is None
    assert "--nope" in check_command("python -m protorch.app.report runs/x --nope")[0]
    page = tmp_path / "page.md"
    page.write_text(
        "text\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n<!-- not measured -->\n| k | v |\n|---|---|\n\n"
        '<!-- measured: commit=abc1234 command="python -m protorch experiment=fig3_toy"\n'
        '     keys="pro.final_reward" -->\n\n| x |\n|---|\n'
    )
    found = tables(page)
    assert [t.kind for t in found] == [None, "not measured", "measured"]
    assert (found[2].commit, found[2].commands, found[2].keys) == (
        "abc1234",
        ["python -m protorch experiment=fig3_toy"],
        ["pro.final_reward"],
    )


# ---- the pages themselves: size, the README's shape, links that resolve ----------------------


MAX_PAGE_LINES = 400
# pages other issues split (docs/physics.md: issue 52, docs/control_loop.md: issue 53)
SPLIT_ELSEWHERE = {"physics.md", "control_loop.md"}
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def markdown_pages() -> list:
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "benchmarks" / "README.md"]
    return [p for p in pages if p.exists()] + sorted(DOCS.rglob("*.md"))


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(
        r"[`*]|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading.strip().lower()
    )
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page) -> set[str]:
    out, seen, fenced = set(), {}, False
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            base = slug(line.lstrip("#"))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(page) -> list[str]:
    bad = []
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    for m in LINK.finditer(text):
        target = m.group(1) or m.group(2)
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    return bad


def test_every_relative_link_of_the_pages_resolves():
    bad = [b for page in markdown_pages() for b in broken_links(page)]
    assert not bad, "broken links:\n  " + "\n  ".join(bad)


def test_no_docs_page_over_400_lines_and_a_changelog_at_the_top():
    long = [
        f"{p.relative_to(ROOT)}: {n}"
        for p in DOCS.rglob("*.md")
        if p.name not in SPLIT_ELSEWHERE and (n := len(p.read_text().splitlines())) > MAX_PAGE_LINES
    ]
    assert not long, f"pages over {MAX_PAGE_LINES} lines (split them by topic): {long}"
    assert (ROOT / "CHANGELOG.md").is_file()


def test_the_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 120, f"README.md has {len(lines)} lines (at most 120)"
    first = next(i for i, line in enumerate(lines, 1) if line.startswith("```python"))
    assert first <= 60, f"the README's first Python block starts at line {first} (at most 60)"
    ci = (ROOT / ".ci" / "run").read_text()
    for command in ('pip install -e ".[test]"', "python -m pytest -q", "pip install torch==2.13.0"):
        assert command in ci and command in "\n".join(lines), (
            command
        )  # CI installs as the README says


def test_the_link_checker_finds_a_missing_file_and_heading(tmp_path):
    page = tmp_path / "a.md"
    (tmp_path / "b.md").write_text("# The arm's default: volumes\n\ntext\n")
    page.write_text(
        "[ok](b.md#the-arms-default-volumes) [gone](c.md) [nohead](b.md#nope) "
        "[web](https://x.org/y.md)\n```\n[in code](d.md)\n```\n"
    )
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert broken_links(page) == [
            "a.md: c.md (no such file)",
            "a.md: b.md#nope (no such heading)",
        ]
    finally:
        ROOT = saved
