"""The headline numbers: declared once per experiment, built from the metrics, printed as a table."""

from __future__ import annotations

from protorch.experiments import EXPERIMENTS
from protorch.experiments.summary import HEADLINES, build_summary, format_summary


def test_every_experiment_declares_headline_numbers():
    assert set(HEADLINES) == set(EXPERIMENTS)
    assert all(HEADLINES[name] for name in EXPERIMENTS)
    # the paper's Fig. 4 relevance times are carried with the row that measures them
    (rel,) = [h for h in HEADLINES["fig4_window"] if h.key == "pro.relevance_seconds"]
    assert rel.paper == {"PRO": 0.02, "RWPO": 84.47}


def test_summary_takes_the_values_from_the_metrics_and_skips_missing_baselines():
    metrics = {"test": {"success_rate": 0.875}, "dynamic": {"success_rate": 0.8},
               "baselines": {"rwr": {"test": {"success_rate": 0.75}}}}
    s = build_summary("point_particle", metrics, run_dir="/x/run", wall_seconds=12.3456)
    assert s["status"] == "ok" and s["run_dir"] == "/x/run" and s["wall_seconds"] == 12.346
    h = s["headline"]
    assert h["test.success_rate"]["value"] == 0.875 and h["test.success_rate"]["method"] == "PRO loop"
    assert h["baselines.rwr.test.success_rate"]["value"] == 0.75
    assert "baselines.demos_only.test.success_rate" not in h  # that baseline was not run
    text = format_summary("point_particle", s)
    assert "held-out success" in text and "0.875" in text and "0.75" in text
    assert text.splitlines()[-1] == "  run folder /x/run" and "wall time 12.3 s" in text


def test_failed_summary_says_so():
    s = build_summary("fig3_toy", {}, run_dir="r", wall_seconds=1.0, status="failed", error="ValueError: bad")
    assert s["headline"] == {}
    assert "status FAILED: ValueError: bad" in format_summary("fig3_toy", s)


def test_the_loops_are_named_after_the_optimisers_that_ran_them():
    metrics = {"settings": {"optimizer": "epro", "baseline_optimizer": "cmaes"}, "test": {"success_rate": 0.9},
               "baselines": {"rwr": {"test": {"success_rate": 0.5}}}}
    h = build_summary("point_particle", metrics, run_dir="r", wall_seconds=1.0)["headline"]
    assert h["test.success_rate"]["method"] == "EPRO loop"
    assert h["baselines.rwr.test.success_rate"]["method"] == "CMA-ES loop"
    arm = build_summary("arm_reach", {"settings": {"optimizer": "cem"}, "test": {"success_rate": 1.0}},
                        run_dir="r", wall_seconds=1.0)["headline"]
    assert arm["test.success_rate"]["method"] == "CEM loop, labels"
    pro = build_summary("arm_reach", {"settings": {"optimizer": "pro"}, "test": {"success_rate": 1.0}},
                        run_dir="r", wall_seconds=1.0)["headline"]
    assert pro["test.success_rate"]["method"] == "PRO loop, labels"
    text = format_summary("point_particle", build_summary("point_particle", metrics, run_dir="r", wall_seconds=1.0))
    assert "EPRO loop" in text and "CMA-ES loop" in text and " PRO loop" not in text
