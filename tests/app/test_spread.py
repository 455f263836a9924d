"""``protorch.app.spread`` (``python -m protorch.app.report SWEEP --spread``): the mean, range and
first seed of each headline number over a sweep's seeds, one group per value of any other swept
parameter; a sweep that does not vary the seed is refused before anything is written; a run
outside a widened range is named."""

from __future__ import annotations

import pytest

from protorch.app import report as rep
from protorch.app.spread import outside, seed_spread, spread_markdown
from tests.app.test_report import make_run

HELD_OUT = {0: 0.99, 1: 0.97, 2: 1.0, 3: 0.985, 4: 0.995}  # per seed


def headline(test: float, moving: float) -> dict:
    return {
        "summary": {
            "headline": {
                "test.success_rate": {
                    "label": "held-out success",
                    "method": "PRO loop",
                    "value": test,
                    "paper": None,
                },
                "dynamic.success_rate": {
                    "label": "moving-environment success",
                    "method": "PRO loop",
                    "value": moving,
                    "paper": None,
                },
            }
        },
        "test": {"success_rate": test},
        "dynamic": {"success_rate": moving},
    }


@pytest.fixture
def seeds(tmp_path):
    root = tmp_path / "seeds"
    for i, (seed, test) in enumerate(HELD_OUT.items()):
        for j, alpha in enumerate((0.001, 0.01)):
            make_run(
                root,
                str(2 * i + j),
                ["experiment=point_particle", f"seed={seed}", f"gp.alpha={alpha}"],
                {"name": "point_particle", "seed": seed, "gp": {"alpha": alpha}},
                headline(test - j * 0.5, 0.9 + 0.01 * seed),
            )
    return root


def test_mean_range_and_first_seed_per_group(seeds):
    groups = seed_spread(rep.collect(seeds))
    assert list(groups) == [(("gp.alpha", 0.001),), (("gp.alpha", 0.01),)]
    held, moving = groups[(("gp.alpha", 0.001),)]  # in the experiment's headline order
    assert held.key == "test.success_rate" and moving.key == "dynamic.success_rate"
    assert held.seeds == [0, 1, 2, 3, 4] and held.values == list(HELD_OUT.values())
    assert held.mean == pytest.approx(sum(HELD_OUT.values()) / 5)
    assert (held.low, held.high, held.first) == (0.97, 1.0, 0.99)
    other = groups[(("gp.alpha", 0.01),)][0]
    assert other.low == pytest.approx(0.47) and other.first == pytest.approx(0.49)
    assert (moving.low, moving.high) == pytest.approx((0.9, 0.94))


def test_a_count_keeps_its_integer_form(tmp_path):
    root = tmp_path / "counts"
    for seed, n in enumerate((71, 158, 114)):
        make_run(
            root,
            str(seed),
            ["experiment=fig4_window", f"seed={seed}"],
            {"name": "fig4_window", "seed": seed},
            {
                "summary": {
                    "headline": {
                        "pro.iterations": {"label": "iterations", "method": "PRO", "value": n}
                    }
                }
            },
        )
    assert "| iterations | PRO | `pro.iterations` | 114 | 71 - 158 | 71 |" in spread_markdown(
        rep.collect(root)
    )


def test_the_table_and_the_cli(seeds, capsys):
    text = spread_markdown(rep.collect(seeds))
    assert "## gp.alpha=0.001" in text and "5 seeds: 0, 1, 2, 3, 4" in text
    assert (
        "| held-out success | PRO loop | `test.success_rate` | 0.988 | 0.970 - 1.000 | 0.990 |"
        in text
    )
    assert rep.main([str(seeds), "--spread", "--no-figure"]) == 0
    assert (seeds / rep.SPREAD_FILE).read_text() == text
    assert "0.970 - 1.000" in capsys.readouterr().out


def test_a_sweep_without_seeds_is_refused_before_writing(tmp_path, capsys):
    root = tmp_path / "grid"
    for i, alpha in enumerate((0.001, 0.01)):
        make_run(
            root,
            str(i),
            ["experiment=point_particle", f"gp.alpha={alpha}"],
            {"name": "point_particle"},
            headline(0.9, 0.9),
        )
    assert rep.main([str(root), "--spread"]) == 2
    assert "does not vary the seed" in capsys.readouterr().err
    assert not (root / rep.SPREAD_FILE).exists() and not (root / "report.md").exists()


def test_another_seed_inside_or_outside_the_widened_range(seeds, tmp_path):
    spreads = seed_spread(rep.collect(seeds))[(("gp.alpha", 0.001),)]
    widen = {"test.success_rate": 0.005, "dynamic.success_rate": 0.01}
    inside = make_run(
        tmp_path / "s11", "0", ["seed=11"], {"name": "point_particle"}, headline(0.966, 0.949)
    )
    low = make_run(
        tmp_path / "s12", "0", ["seed=12"], {"name": "point_particle"}, headline(0.964, 0.951)
    )
    assert outside(spreads, rep.collect(inside).runs[0], widen) == {}
    bad = outside(spreads, rep.collect(low).runs[0], widen)
    assert set(bad) == {"test.success_rate", "dynamic.success_rate"}
    assert bad["test.success_rate"] == pytest.approx((0.964, 0.965, 1.005))
    with pytest.raises(KeyError, match="loop.seconds"):
        outside(spreads, rep.collect(inside).runs[0], {"loop.seconds": 1.0})
