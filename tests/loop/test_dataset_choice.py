"""``choice="dataset"``: the loop iterates the initial data set's own environments (the paper's
arm loop over its initialisation environments)."""

from __future__ import annotations

import pytest
import torch

from protorch import PRO, make_env_map
from protorch.loop import LoopSettings, OptimizerSpec, self_improve

from .test_loop import setup


def run(ds, num_envs, **kw):
    task, promp, _ = setup()
    return self_improve(
        task,
        promp,
        ds,
        OptimizerSpec(
            PRO, {"beta": 20.0, "num_samples": 20, "max_iter": 5, "relevance_samples": 20}
        ),
        lambda: make_env_map("torch", 1.0),
        LoopSettings(
            num_envs=num_envs,
            batch_size=2,
            add_only="all",
            seed=0,
            choice="dataset",
            refill=False,
            eval_dtype=None,
            **kw,
        ),
    )


def test_the_pool_is_the_data_sets_distinct_environments_in_order():
    _, _, ds = setup(num_demo_envs=4)  # 4 environments x 2 demonstrations: 4 entries
    known = ds.env.clone()  # (4, 2)
    res = run(ds, 3)
    assert torch.equal(res.pool, known[:3])
    assert res.tried == [0, 1, 2]
    assert len(res.dataset) == 4 + 3  # each tried environment added once more (add_only="all")
    assert torch.equal(res.dataset.env[4:], known[:3])


def test_more_environments_than_the_data_set_holds_is_refused():
    _, _, ds = setup(num_demo_envs=4)
    with pytest.raises(ValueError, match="4 distinct"):
        run(ds, 5)
