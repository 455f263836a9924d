"""Each experiment's headline rows (:class:`Headline`), one list per experiment; the experiment's
class in :mod:`protorch.experiments.registry` names its list and
:mod:`protorch.experiments.summary` builds the run summary from it."""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "Headline",
    "FIG3_TOY",
    "FIG4_WINDOW",
    "BEAM_WINDOW",
    "TELEOP_WINDOW",
    "POINT_PARTICLE",
    "SELF_IMPROVE",
    "ARM_REACH",
]


class Headline(NamedTuple):
    label: str
    key: str
    method: str
    baselines: tuple = ()
    paper: dict = {}


FIG3_TOY: list[Headline] = [  # experiment=fig3_toy
    Headline(
        "irrelevant std, final / initial",
        "pro.irrelevant_std_ratio",
        "PRO",
        (("RWR", "rwr.irrelevant_std_ratio"),),
    ),
    Headline("final reward", "pro.final_reward", "PRO", (("RWR", "rwr.final_reward"),)),
]

FIG4_WINDOW: list[Headline] = [  # experiment=fig4_window
    Headline(
        "relevance time",
        "pro.relevance_seconds",
        "PRO",
        (("RWPO", "rwpo.relevance_seconds"),),
        {"PRO": 0.02, "RWPO": 84.47},
    ),
    Headline(
        "mean passes start, window, end",
        "pro.success",
        "PRO",
        (("RWPO", "rwpo.success"), ("demos", "demos.success_rate")),
    ),
    Headline("iterations", "pro.iterations", "PRO", (("RWPO", "rwpo.iterations"),)),
]

BEAM_WINDOW: list[Headline] = [  # experiment=beam_window
    Headline(
        "success rate",
        "optimized.samples_success_rate",
        "PRO samples",
        (("demonstrations", "demos.success_rate"),),
        {"demonstrations": 0.0},
    ),
    Headline(
        "teleoperation success",
        "teleop.assisted_success_rate",
        "guided by PRO",
        (
            ("unassisted", "teleop.unassisted_success_rate"),
            ("guided by demos", "teleop.assisted_by_demos_promp_success_rate"),
        ),
    ),
]

TELEOP_WINDOW: list[Headline] = [  # experiment=teleop_window
    Headline(
        label,
        f"teleop.adaptive.{key}",
        "adaptive guide",
        (("fixed guide", f"teleop.fixed.{key}"), ("no guide", f"teleop.none.{key}")),
    )
    for label, key in (
        ("success rate", "success_rate"),
        ("collision rate", "collision_rate"),
        ("median trial time (s)", "time"),
        ("effort (m s)", "effort"),
        ("freedom (compliance)", "freedom"),
    )
] + [
    Headline(
        "adaptive guide's freedom, by the map's optimiser",
        "freedom.pro.freedom",
        "PRO",
        (("CEM", "freedom.cem.freedom"), ("CMA-ES", "freedom.cmaes.freedom")),
    ),
    Headline(
        "adaptive guide's success, by the map's optimiser",
        "freedom.pro.success_rate",
        "PRO",
        (("CEM", "freedom.cem.success_rate"), ("CMA-ES", "freedom.cmaes.success_rate")),
    ),
]

POINT_PARTICLE: list[Headline] = [  # experiment=point_particle
    Headline(
        "held-out success",
        "test.success_rate",
        "{optimizer} loop",
        (
            ("demos only", "baselines.demos_only.test.success_rate"),
            ("{baseline} loop", "baselines.rwr.test.success_rate"),
        ),
    ),
    Headline(
        "moving-environment success",
        "dynamic.success_rate",
        "{optimizer} loop",
        (
            ("demos only", "baselines.demos_only.dynamic.success_rate"),
            ("{baseline} loop", "baselines.rwr.dynamic.success_rate"),
        ),
    ),
    Headline(
        "the authors' moving test (wall, hole, goal moving)",
        "dynamic_paper.success_rate",
        "{optimizer} loop",
    ),
    Headline(
        "rollouts (samples evaluated)",
        "loop.rollouts",
        "{optimizer} loop",
        (("{baseline} loop", "baselines.rwr.loop.rollouts"),),
    ),
    Headline(
        "loop time",
        "loop.seconds",
        "{optimizer} loop",
        (("{baseline} loop", "baselines.rwr.loop.seconds"),),
    ),
]

SELF_IMPROVE: list[Headline] = [  # experiment=self_improve
    Headline(
        "held-out success",
        "test.success_rate",
        "{optimizer} loop",
        (("demos only", "demos_only.test.success_rate"),),
    ),
    Headline("rollouts (samples evaluated)", "loop.rollouts", "{optimizer} loop"),
    Headline("loop time", "loop.seconds", "{optimizer} loop"),
]

ARM_REACH: list[Headline] = [  # experiment=arm_reach
    Headline(
        "held-out success",
        "test.success_rate",
        "{optimizer} loop, labels",
        (
            ("labels dropped", "baselines.labels_off.test.success_rate"),
            ("loop without labels", "baselines.labels_off_loop.test.success_rate"),
        ),
    ),
    Headline(
        "moving-environment success",
        "dynamic.success_rate",
        "{optimizer} loop, labels",
        (
            ("labels dropped", "baselines.labels_off.dynamic.success_rate"),
            ("loop without labels", "baselines.labels_off_loop.dynamic.success_rate"),
        ),
    ),
    Headline(
        "side switches (labels)",
        "dynamic.switches",
        "{optimizer} loop, labels",
        (
            ("labels dropped", "baselines.labels_off.dynamic.switches"),
            ("loop without labels", "baselines.labels_off_loop.dynamic.switches"),
        ),
    ),
    Headline(
        "side switches (geometric)",
        "dynamic.switches_geometric",
        "{optimizer} loop, labels",
        (
            ("labels dropped", "baselines.labels_off.dynamic.switches_geometric"),
            ("loop without labels", "baselines.labels_off_loop.dynamic.switches_geometric"),
        ),
    ),
    Headline(
        "rollouts (samples evaluated)",
        "loop.rollouts",
        "{optimizer} loop, labels",
        (("loop without labels", "baselines.labels_off_loop.loop.rollouts"),),
    ),
    Headline(
        "loop time",
        "loop.seconds",
        "{optimizer} loop, labels",
        (("loop without labels", "baselines.labels_off_loop.loop.seconds"),),
    ),
    Headline("held-out success in MuJoCo", "physics.test.success_rate", "{optimizer} loop, labels"),
    Headline(
        "moving success in MuJoCo", "physics.dynamic.success_rate", "{optimizer} loop, labels"
    ),
    Headline(
        "moving episodes touching in MuJoCo",
        "physics.dynamic.contacts",
        "{optimizer} loop, labels",
    ),
]
