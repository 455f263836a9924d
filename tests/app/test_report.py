"""``python -m protorch.app.report``: a sweep folder becomes one table (CSV, Markdown) and a figure;
clear errors for folders that are not sweeps; atomic outputs. The launchers' real sweeps are
reported in tests/test_sweeps.py; here the folders are written by hand, so each case is exact."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from protorch.app import report as rep


def make_run(
    root: Path, name: str, overrides: list[str], config: dict, metrics: dict | None
) -> Path:
    d = root / name
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (d / "config.yaml").write_text(json.dumps(config))  # JSON is YAML
    if metrics is not None:
        (d / "metrics.json").write_text(json.dumps(metrics))
    return d


GRID = [(b, a) for b in (10.0, 20.0, 40.0) for a in (0.001, 0.01)]


def metrics_for(i: int, beta: float, alpha: float) -> dict:
    return {
        "experiment": "point_particle",
        "test": {"success_rate": 0.5 + 0.01 * i, "num_envs": 200},
        "dynamic": {"success_rate": 0.4},
        "loop": {"seconds": 1.0 + i, "success_rate": 0.9},
        "seconds": 2.0 + i,
        "objective": {"metric": "test.success_rate", "value": 0.5 + 0.01 * i},
        "baselines": {"rwr": {"test": {"success_rate": 1.0}}},
        "relevance": [0.1, 0.2],
        "settings": {"beta": beta, "alpha": alpha},
    }


@pytest.fixture
def sweep(tmp_path) -> Path:
    root = tmp_path / "sweep"
    for i, (beta, alpha) in enumerate(GRID):
        cfg = {
            "name": "point_particle",
            "seed": 0,
            "optimizer": {"beta": beta, "num_samples": 20},
            "gp": {"alpha": alpha},
            "settings": {"baselines": []},
        }
        make_run(
            root,
            str(i),
            [
                "experiment=point_particle",
                f"optimizer.beta={beta:g}",
                f"gp.alpha={alpha:g}",
                "optimizer.num_samples=20",
            ],
            cfg,
            metrics_for(i, beta, alpha),
        )
    (root / "multirun.yaml").write_text("hydra: {}\n")
    (root / ".submitit").mkdir()  # launcher bookkeeping is not a run
    (root / "0" / "baselines" / "rwr").mkdir(parents=True)  # the inside of a run is not a run
    (root / "0" / "baselines" / "rwr" / "metrics.json").write_text("{}")
    return root


def test_collect_finds_every_run_and_what_was_swept(sweep):
    r = rep.collect(sweep)
    assert [x.name for x in r.runs] == [str(i) for i in range(6)]
    assert r.swept == ["optimizer.beta", "gp.alpha"]
    assert r.fixed == {"experiment": "point_particle", "optimizer.num_samples": 20}
    assert [(x.param("optimizer.beta"), x.param("gp.alpha")) for x in r.runs] == GRID
    assert r.objective_metric() == "test.success_rate"
    success, time = r.headline()
    assert success == [
        "dynamic.success_rate",
        "loop.success_rate",
        "test.success_rate",
    ]  # not baselines.*
    assert time == ["loop.seconds", "seconds"]


def test_csv_and_markdown_have_a_row_per_run_with_parameters_and_metrics(sweep, tmp_path):
    out = tmp_path / "out"
    paths = rep.write_report(rep.collect(sweep), out)
    assert sorted(p.name for p in paths.values()) == ["report.csv", "report.md", "report.png"]
    rows = list(csv.DictReader(paths["csv"].open()))
    assert len(rows) == 6
    for i, (row, (beta, alpha)) in enumerate(zip(rows, GRID)):
        assert row["run"] == str(i) and row["status"] == "ok"
        assert float(row["optimizer.beta"]) == beta and float(row["gp.alpha"]) == alpha
        assert float(row["test.success_rate"]) == pytest.approx(0.5 + 0.01 * i)
        assert float(row["loop.seconds"]) == 1.0 + i
        assert row["experiment"] == "point_particle"
    assert "relevance" not in rows[0]  # lists are not scalar metrics
    md = paths["md"].read_text().splitlines()
    table = [line for line in md if line.startswith("| ") and not line.startswith("| run")]
    assert len(table) == 6
    head = next(line for line in md if line.startswith("| run"))
    assert head.split(" | ")[1:3] == ["optimizer.beta", "gp.alpha"]
    assert "objective (test.success_rate)" in head
    assert table[5].split(" | ")[1:4] == ["40", "0.01", "0.55"]
    assert paths["png"].stat().st_size > 10_000
    assert not list(out.glob("*.tmp*"))


def test_a_run_without_metrics_keeps_its_row(sweep):
    (sweep / "3" / "metrics.json").unlink()
    r = rep.collect(sweep)
    assert [x.status for x in r.runs] == ["ok"] * 3 + ["no metrics.json"] + ["ok"] * 2
    md = rep.to_markdown(r, *r.headline())
    assert "| 3 | 20 | 0.01 |" in md and "no metrics.json |" in md


def test_optuna_results_are_summarised(sweep):
    (sweep / "optimization_results.yaml").write_text(
        "name: optuna\nbest_params:\n  optimizer.beta: 20.0\n  gp.alpha: 0.01\nbest_value: 0.53\n"
    )
    md = rep.to_markdown(rep.collect(sweep), [], [])
    assert "Optuna: best value 0.53 at `optimizer.beta=20`, `gp.alpha=0.01`" in md


def test_runs_without_overrides_are_compared_by_their_configs(tmp_path):
    """hydra.output_subdir=null leaves no .hydra/: the swept keys are the config entries that
    differ."""
    for i, beta in enumerate((1.0, 5.0)):
        d = tmp_path / f"r{i}"
        d.mkdir()
        (d / "config.yaml").write_text(
            json.dumps({"name": "fig3_toy", "optimizer": {"beta": beta}})
        )
        (d / "metrics.json").write_text(json.dumps({"pro": {"seconds": 0.1}}))
    r = rep.collect(tmp_path)
    assert r.swept == ["optimizer.beta"] and r.fixed == {}


def test_cli_writes_and_prints_the_table(sweep, capsys):
    assert (
        rep.main([str(sweep), "--no-figure", "--success", "test.success_rate", "--time", "seconds"])
        == 0
    )
    out = capsys.readouterr().out
    assert (
        "| run | optimizer.beta | gp.alpha | objective (test.success_rate) | seconds | status |"
        in out
    )
    assert (sweep / "report.csv").is_file() and not (sweep / "report.png").exists()


# --------------------------------------------------------------------------- errors
def test_missing_folder_and_file(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        rep.collect(tmp_path / "nope")
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        rep.collect(f)
    assert rep.main([str(tmp_path / "nope")]) == 2
    assert "protorch.app.report: error:" in capsys.readouterr().err


@pytest.mark.parametrize("layout", ["empty", "foreign"])
def test_a_folder_that_is_not_a_sweep(tmp_path, layout, capsys):
    if layout == "foreign":
        (tmp_path / "notes.txt").write_text("hello")
        (tmp_path / "data").mkdir()
        (tmp_path / "data" / "table.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="no runs under .*hydra.sweep.dir"):
        rep.collect(tmp_path)
    assert rep.main([str(tmp_path)]) == 2
    assert "no runs under" in capsys.readouterr().err
    assert not list(tmp_path.glob("report.*"))


def test_runs_that_all_failed(sweep):
    for i in range(6):
        (sweep / str(i) / "metrics.json").unlink()
    with pytest.raises(ValueError, match="none of the 6 run.* has a metrics.json"):
        rep.collect(sweep)


@pytest.mark.parametrize(
    "content, message", [("{not json", "is not valid JSON"), ("[1, 2]", "expected a JSON object")]
)
def test_bad_metrics_file_is_named(sweep, content, message):
    (sweep / "2" / "metrics.json").write_text(content)
    with pytest.raises(ValueError, match=f"2/metrics.json.*{message}|{message}"):
        rep.collect(sweep)


def test_bad_overrides_file_is_named(sweep):
    (sweep / "1" / ".hydra" / "overrides.yaml").write_text("- justaword\n")
    with pytest.raises(ValueError, match="overrides.yaml: 'justaword' is not a key=value override"):
        rep.collect(sweep)


def test_unknown_metric_is_refused_before_anything_is_written(sweep, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="no run has a metric 'test.succes'"):
        rep.write_report(rep.collect(sweep), out, success=["test.succes"])
    assert not out.exists()


def test_a_failed_write_leaves_the_previous_report_whole(sweep, monkeypatch):
    rep.write_report(rep.collect(sweep), figure=False)
    before = (sweep / "report.csv").read_bytes()
    calls = {"n": 0}
    real = csv.DictWriter.writerow

    def flaky(self, row):
        calls["n"] += 1
        if calls["n"] == 4:
            raise OSError("disk full")
        return real(self, row)

    monkeypatch.setattr(csv.DictWriter, "writerow", flaky)
    with pytest.raises(OSError, match="disk full"):
        rep.write_report(rep.collect(sweep), figure=False)
    assert (sweep / "report.csv").read_bytes() == before
    assert not list(sweep.glob("*.tmp*"))
