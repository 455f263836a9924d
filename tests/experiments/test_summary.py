"""The headline numbers: declared once per experiment, built from the metrics, printed
as a table."""

from __future__ import annotations

import math

from protorch.experiments import EXPERIMENTS
from protorch.experiments.summary import (
    HEADLINES,
    baseline_settings,
    build_summary,
    format_summary,
    format_value,
)


def test_every_experiment_declares_headline_numbers():
    assert set(HEADLINES) == set(EXPERIMENTS)
    assert all(HEADLINES[name] for name in EXPERIMENTS)
    # the paper's Fig. 4 relevance times are carried with the row that measures them
    (rel,) = [h for h in HEADLINES["fig4_window"] if h.key == "pro.relevance_seconds"]
    assert rel.paper == {"PRO": 0.02, "RWPO": 84.47}


def test_summary_takes_the_values_from_the_metrics_and_skips_missing_baselines():
    metrics = {
        "test": {"success_rate": 0.875},
        "dynamic": {"success_rate": 0.8},
        "baselines": {"rwr": {"test": {"success_rate": 0.75}}},
    }
    s = build_summary("point_particle", metrics, run_dir="/x/run", wall_seconds=12.3456)
    assert s["status"] == "ok" and s["run_dir"] == "/x/run" and s["wall_seconds"] == 12.346
    h = s["headline"]
    assert (
        h["test.success_rate"]["value"] == 0.875 and h["test.success_rate"]["method"] == "PRO loop"
    )
    assert h["baselines.rwr.test.success_rate"]["value"] == 0.75
    assert "baselines.demos_only.test.success_rate" not in h  # that baseline was not run
    text = format_summary("point_particle", s)
    assert "held-out success" in text and "0.875" in text and "0.750" in text
    assert text.splitlines()[-1] == "  run folder /x/run" and "wall time: run 12.3 s" in text
    assert (
        s["process_seconds"] is None or s["process_seconds"] > 0
    )  # Linux: this test process's age
    if s["process_seconds"] is not None:
        assert f"process {s['process_seconds']:.1f} s" in text


def test_values_print_with_the_fixed_precision_of_their_kind():
    assert [format_value("test.success_rate", v) for v in (0, 1, 0.7, 0.99, 1.0, 0.995)] == [
        "0.000",
        "1.000",
        "0.700",
        "0.990",
        "1.000",
        "0.995",
    ]
    assert (
        format_value("loop.seconds", 41.26) == "41.3 s"
        and format_value("pro.relevance_seconds", 0.0011) == "1.1 ms"
    )
    assert (
        format_value("loop.rollouts", 1234567) == "1,234,567"
        and format_value("dynamic.switches", 33) == "33"
    )
    assert (
        format_value("pro.irrelevant_std_ratio", 1.0) == "1.00"
        and format_value("x.ratio", 0.000312) == "0.000312"
    )
    assert (
        format_value("pro.iterations", 114.2) == "114"
        and format_value("pro.iterations", 71.0) == "71.0"
    )
    assert format_value("pro.success", True) == "yes" and format_value("a.rate", None) == "-"
    assert format_value("dynamic.success_rate", math.nan) == "n/a"
    # a metric another module adds prints by its kind too
    assert (
        format_value("physics.tracking_error_rate", 0.5) == "0.500"
        and format_value("physics.sim_seconds", 2) == "2.0 s"
    )


def test_the_paper_column_is_there_only_where_the_paper_states_a_number():
    pp = format_summary(
        "point_particle",
        build_summary(
            "point_particle", {"test": {"success_rate": 1.0}}, run_dir="r", wall_seconds=1.0
        ),
    )
    assert "paper" not in pp.splitlines()[1]
    fig4 = build_summary(
        "fig4_window",
        {"pro": {"relevance_seconds": 0.0011}, "rwpo": {"relevance_seconds": 3.3}},
        run_dir="r",
        wall_seconds=1.0,
    )
    text = format_summary("fig4_window", fig4)
    assert (
        "paper" in text.splitlines()[1]
        and "20.0 ms" in text
        and "84.5 s" in text
        and "1.1 ms" in text
    )


def test_a_baseline_following_the_loop_optimisers_settings_says_so():
    b = baseline_settings(
        {
            "name": "epro",
            "beta": None,
            "num_samples": 20,
            "max_iter": 200,
            "tol": 1e-3,
            "window": 5,
        },
        {"name": "rwr", "beta": 20.0, "num_samples": 20, "max_iter": 200, "tol": 1e-3, "window": 5},
    )
    assert b["same"] == {"num_samples": 20, "max_iter": 200, "tol": 1e-3, "window": 5} and b[
        "own"
    ] == {"beta": 20.0}
    metrics = {
        "settings": {"optimizer": "epro"},
        "test": {"success_rate": 1.0},
        "baselines": {"rwr": {"test": {"success_rate": 0.93}}},
    }
    text = format_summary(
        "point_particle",
        build_summary("point_particle", metrics, run_dir="r", wall_seconds=1.0, baseline=b),
    )
    assert (
        "baseline RWR runs with num_samples=20, max_iter=200, tol=0.001, window=5 as the EPRO run"
        in text
    )
    assert "its own beta=20.0" in text
    # no baseline loop in the run: no line about it
    alone = build_summary(
        "point_particle", {"test": {"success_rate": 1.0}}, run_dir="r", wall_seconds=1.0, baseline=b
    )
    assert "baseline" not in alone and baseline_settings({"name": "pro"}, None) is None


def test_failed_summary_says_so():
    s = build_summary(
        "fig3_toy", {}, run_dir="r", wall_seconds=1.0, status="failed", error="ValueError: bad"
    )
    assert s["headline"] == {}
    assert "status FAILED: ValueError: bad" in format_summary("fig3_toy", s)
    assert "metric" not in format_summary("fig3_toy", s)  # no empty table


def test_the_loops_are_named_after_the_optimisers_that_ran_them():
    metrics = {
        "settings": {"optimizer": "epro", "baseline_optimizer": "cmaes"},
        "test": {"success_rate": 0.9},
        "baselines": {"rwr": {"test": {"success_rate": 0.5}}},
    }
    h = build_summary("point_particle", metrics, run_dir="r", wall_seconds=1.0)["headline"]
    assert h["test.success_rate"]["method"] == "EPRO loop"
    assert h["baselines.rwr.test.success_rate"]["method"] == "CMA-ES loop"
    arm = build_summary(
        "arm_reach",
        {"settings": {"optimizer": "cem"}, "test": {"success_rate": 1.0}},
        run_dir="r",
        wall_seconds=1.0,
    )["headline"]
    assert arm["test.success_rate"]["method"] == "CEM loop, labels"
    pro = build_summary(
        "arm_reach",
        {"settings": {"optimizer": "pro"}, "test": {"success_rate": 1.0}},
        run_dir="r",
        wall_seconds=1.0,
    )["headline"]
    assert pro["test.success_rate"]["method"] == "PRO loop, labels"
    text = format_summary(
        "point_particle", build_summary("point_particle", metrics, run_dir="r", wall_seconds=1.0)
    )
    assert "EPRO loop" in text and "CMA-ES loop" in text and " PRO loop" not in text
