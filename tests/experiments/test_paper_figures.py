"""The paper's claims, reproduced at the paper's budgets (each run takes seconds)."""

from __future__ import annotations

import pytest
import torch

from protorch.experiments import run_experiment


def _cfg(name, **optimizer):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from protorch.app.main import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        cfg = compose(config_name="config", overrides=[f"experiment={name}", "plot=false"])
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    plain["optimizer"].update(optimizer)
    return OmegaConf.to_container(
        OmegaConf.create(plain), resolve=True
    )  # baseline_optimizer: ${optimizer.*}


def test_fig3_pro_keeps_the_irrelevant_std_and_rwr_loses_it(tmp_path):
    m = run_experiment(_cfg("fig3_toy"), tmp_path)
    init = m["initial_std"][0]
    assert abs(m["pro"]["final_std"][0] / init - 1) <= 0.2  # PRO keeps it (within 20 %)
    assert m["rwr"]["final_std"][0] / init < 0.05  # RWR collapses it (below 5 %)
    assert m["pro"]["final_std"][1] < 0.05 and m["rwr"]["final_std"][1] < 0.05  # both solve w2
    r_pro, r_rwr = m["pro"]["final_reward"], m["rwr"]["final_reward"]
    assert abs(r_pro - r_rwr) / max(r_pro, r_rwr) <= 0.10


@pytest.mark.slow
def test_fig4_both_methods_pass_start_window_and_end(tmp_path):
    m = run_experiment(_cfg("fig4_window"), tmp_path)
    # the demonstrations alone do not: their mean misses the window centre
    assert m["demos"]["mean_trajectory"]["window"] > 0.05
    for method in ("pro", "rwpo"):
        for key in ("start", "window", "end"):
            assert m[method][key] < 0.1, (method, key, m[method][key])
    # PRO computes a relevance every iteration, RWPO learns it once
    assert m["pro"]["relevance_computations"] == m["pro"]["iterations"]
    assert m["rwpo"]["relevance_computations"] == 1
    assert torch.tensor(m["pro"]["relevance"]).max() <= 1.0
