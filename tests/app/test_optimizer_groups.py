"""Every optimizer group option composes with the self-improvement experiments at its own defaults.

``experiment=point_particle`` and ``experiment=arm_reach`` set PRO's reward temperature; it lives
in ``conf/experiment_optimizer/<experiment>/<optimizer>.yaml`` (merged only for that optimiser),
so ``optimizer=epro`` keeps its self-set beta and ``optimizer=cem | cmaes`` get none, while the
default command composes the paper's PRO settings exactly.
"""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app.main import config_dir
from protorch.experiments import arm_reach, check_config, point_particle
from protorch.experiments.common import optimizer_spec, problem_arguments
from protorch.optim import OPTIMIZERS

CONF = Path(config_dir())
OPTIONS = sorted(p.stem for p in (CONF / "optimizer").glob("*.yaml"))
EXPERIMENTS = {"point_particle": point_particle, "arm_reach": arm_reach}
# small problem sizes, so building an experiment takes a fraction of a second
SMALL = {
    "point_particle": [
        "settings.test.num_envs=4",
        "settings.dynamic.episodes=1",
        "settings.dynamic_paper.episodes=1",
    ],
    "arm_reach": [
        "task.priors=0",  # the priors' IK is most of a build and no optimiser reads them apart
        "task.demo_envs=2",
        "settings.test.num_envs=4",
        "settings.dynamic.episodes=1",
    ],
}


def composed(*overrides: str) -> dict:
    """The resolved config of ``python -m protorch <overrides>`` (without the hydra node)."""
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        c = compose(config_name="config", overrides=list(overrides))
    plain = OmegaConf.to_container(c, resolve=False)
    plain.pop("hydra", None)
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def yaml_dict(path: Path) -> dict:
    return OmegaConf.to_container(OmegaConf.load(path)) if path.is_file() else {}


def test_the_registry_has_a_group_option_for_every_optimiser():
    assert OPTIONS == sorted(OPTIMIZERS)


@pytest.mark.parametrize("experiment", sorted(EXPERIMENTS))
@pytest.mark.parametrize("option", OPTIONS)
def test_each_optimizer_option_gets_its_own_defaults(experiment, option):
    cfg = composed(f"experiment={experiment}", f"optimizer={option}")
    own = yaml_dict(CONF / "optimizer" / f"{option}.yaml")
    shared = yaml_dict(CONF / "experiment" / f"{experiment}.yaml")[
        "optimizer"
    ]  # what every optimiser gets
    tuned = yaml_dict(CONF / "experiment_optimizer" / experiment / f"{option}.yaml")
    assert (
        "beta" not in shared
    )  # the experiment's temperature is per optimiser, never for all of them
    assert cfg["optimizer"] == {**own, **shared, **tuned}
    if option == "epro":
        assert cfg["optimizer"]["beta"] is None and cfg["optimizer"]["num_samples"] == 20
    if option in ("cem", "cmaes"):
        assert "beta" not in cfg["optimizer"]
    if option in ("pro", "rwr", "rwpo"):
        assert cfg["optimizer"]["beta"] == {"point_particle": 20.0, "arm_reach": 200.0}[experiment]


@pytest.mark.parametrize(
    "experiment",
    [
        pytest.param(e, marks=pytest.mark.slow) if e == "arm_reach" else e
        for e in sorted(EXPERIMENTS)
    ],
)  # the arm builds IK demonstrations: seconds
@pytest.mark.parametrize("option", OPTIONS)
def test_each_optimizer_option_builds_through_the_registry(experiment, option):
    module = EXPERIMENTS[experiment]
    small = (
        ["optimizer.theta_samples=4", "optimizer.trajectory_samples=3"] if option == "rwpo" else []
    )
    settings = check_config(
        composed(f"experiment={experiment}", f"optimizer={option}", *SMALL[experiment], *small)
    )
    cls, _ = optimizer_spec(settings["optimizer"])
    assert cls is OPTIMIZERS[option]
    accepted = inspect.signature(module.prepare).parameters
    setup = module.prepare(**{k: v for k, v in settings.items() if k in accepted})
    args = setup.loop_arguments(None)
    assert args["optimizer"] is cls
    kwargs = problem_arguments(cls, args["optimizer_kwargs"], setup.task, setup.promp)
    n = setup.promp.num_weights
    opt = cls(
        torch.zeros(2, n, dtype=torch.float64),
        torch.full((2, n), 0.1, dtype=torch.float64),
        seed=0,
        **kwargs,
    )
    w = opt.ask()  # (B, S, N)
    assert w.shape[0] == 2 and w.shape[-1] == n
    if option != "rwpo":  # RWPO asks first for its relevance search's samples
        assert w.shape[1] == kwargs["num_samples"]
    opt.tell(torch.rand(*w.shape[:2], setup.task.num_objectives, dtype=w.dtype))


def pro_settings(beta: float, max_iter: int) -> list[tuple]:
    """The paper's PRO settings in the config's order, ``beta`` and ``max_iter`` aside."""
    return [
        ("name", "pro"),
        ("beta", beta),
        ("num_samples", 100),
        ("max_iter", max_iter),
        ("tol", 1e-3),
        ("window", 5),
        ("relevance_samples", 100),
        ("relevance_var", 1e-5),
        ("relevance_every", 1),
        ("noise_floor", None),
    ]


def test_the_default_point_particle_optimizers_are_the_papers():
    cfg = composed("experiment=point_particle")
    assert list(cfg["optimizer"].items()) == pro_settings(20.0, 200) + [("convergence", "mean")]
    assert list(cfg["baseline_optimizer"].items()) == [
        ("name", "rwr"),
        ("beta", 20.0),
        ("num_samples", 100),
        ("max_iter", 200),
        ("tol", 1e-3),
        ("window", 5),
        ("center", "new"),
        ("convergence", "mean"),
    ]


def test_the_default_arm_optimizer_is_the_papers():
    cfg = composed("experiment=arm_reach")
    assert list(cfg["optimizer"].items()) == pro_settings(200.0, 50)


@pytest.mark.parametrize(
    "option, beta", [("pro", 20.0), ("epro", 20.0), ("cem", 20.0), ("cmaes", 20.0)]
)
def test_the_rwr_baseline_keeps_a_temperature_whatever_the_loop_runs(option, beta):
    # the loop's beta where it has one; 20 where it sets its own (EPRO) or takes none (CEM, CMA-ES)
    assert (
        composed("experiment=point_particle", f"optimizer={option}")["baseline_optimizer"]["beta"]
        == beta
    )
    assert composed(
        "experiment=point_particle",
        f"optimizer={option}",
        *([] if option in ("cem", "cmaes") else ["optimizer.beta=7"]),
    )["baseline_optimizer"]["beta"] == (20.0 if option in ("cem", "cmaes") else 7.0)


def test_an_experiment_without_optimizer_files_takes_the_group_as_it_is():
    # self_improve names no experiment_optimizer file: the optimizer group as it is
    cfg = composed("experiment=self_improve", "optimizer=epro")
    assert cfg["optimizer"] == yaml_dict(CONF / "optimizer" / "epro.yaml")
