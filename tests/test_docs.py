"""The docs' tables cannot go stale silently (the convention: tests/docs_tables.py): every table
says whether it holds measurements; a measured one names the commit its numbers came from, a
command that still exists (overrides Hydra and the settings' checks accept, a script and flags
that are still there) and metrics keys the command's experiment still writes. Nothing is re-run."""

from __future__ import annotations

import subprocess

import pytest

from protorch.experiments.summary import HEADLINES
from tests.docs_tables import DOCS, ROOT, COMMIT, Table, check_command, recorded_keys, tables

# pages whose tables are not yet annotated (each one's tables still to be given a comment)
PENDING = {"benchmarks.md", "peers.md"}
PAGES = sorted(p for p in DOCS.rglob("*.md") if p.name not in PENDING)
MEASURED = [t for p in PAGES for t in tables(p) if t.kind == "measured"]


def _git(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def test_every_table_says_whether_it_holds_measurements():
    bare = [t.where() for p in PAGES for t in tables(p) if t.kind is None]
    assert not bare, "tables without a <!-- measured: ... --> or <!-- not measured --> comment: " + ", ".join(bare)
    assert MEASURED, "no measured table found: the convention is not applied"


@pytest.mark.parametrize("table", MEASURED, ids=Table.where)
def test_a_measured_table_names_its_commit_command_and_keys(table):
    assert table.error is None, f"{table.where()}: {table.error}"
    assert table.commit and COMMIT.match(table.commit), f"{table.where()}: commit={table.commit!r} is not a hash"
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
            assert name in known, f"{table.where()}: no recorded metrics keys for {name} (tests/docs_metric_keys.json)"
            missing = [k for k in table.keys if k not in known[name]]
            assert not missing, f"{table.where()}: {name}'s metrics hold no {', '.join(missing)}"


def test_the_named_commits_exist_where_the_history_is_here():
    if _git("rev-parse", "--git-dir").returncode != 0 or _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        pytest.skip("no full git history in this checkout")
    unknown = sorted({f"{t.where()}: {t.commit}" for t in MEASURED
                      if t.commit and _git("cat-file", "-e", f"{t.commit}^{{commit}}").returncode != 0})
    assert not unknown, "commits not in this repository: " + ", ".join(unknown)


def test_the_recorded_keys_hold_every_headline_of_the_experiments_they_cover():
    """The record comes from real runs; a headline key the code renamed is missing from it."""
    for name, keys in recorded_keys().items():
        missing = [row.key for row in HEADLINES.get(name, []) if row.key not in keys]
        assert not missing, f"{name}: headline keys {missing} are not in the recorded metrics; record a fresh run"


def test_the_checks_catch_what_went_stale(tmp_path):
    assert check_command("python -m protorch experiment=point_particle threads=1")[0] is None
    assert check_command("MKL_CBWR=AVX2 python -m protorch -m experiment=fig4_window seed=0,1 hydra.sweep.dir=x")[0] is None
    assert "no_such_key" in check_command("python -m protorch experiment=point_particle settings.no_such_key=1")[0]
    assert "experiment" in check_command("python -m protorch experiment=no_such_experiment")[0]
    assert check_command("python benchmarks/reproducibility.py --ops")[0] is None
    assert "--no-such-flag" in check_command("python benchmarks/reproducibility.py --no-such-flag")[0]
    assert "does not exist" in check_command("python benchmarks/no_such_script.py")[0]
    assert check_command("python -m protorch.app.report runs/x --spread")[0] is None
    assert "--nope" in check_command("python -m protorch.app.report runs/x --nope")[0]
    page = tmp_path / "page.md"
    page.write_text("text\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n<!-- not measured -->\n| k | v |\n|---|---|\n\n"
                    '<!-- measured: commit=abc1234 command="python -m protorch experiment=fig3_toy"\n'
                    '     keys="pro.final_reward" -->\n\n| x |\n|---|\n')
    found = tables(page)
    assert [t.kind for t in found] == [None, "not measured", "measured"]
    assert (found[2].commit, found[2].commands, found[2].keys) == (
        "abc1234", ["python -m protorch experiment=fig3_toy"], ["pro.final_reward"])
