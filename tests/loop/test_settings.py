"""LoopSettings: validation before any work, the number of steps, the per-step seed."""

from __future__ import annotations

import pytest

from protorch.loop import ADD_ONLY, CHOICES, LoopSettings


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"num_envs": -1}, "num_envs must be an int >= 0"),
        ({"num_envs": 2.5}, "num_envs"),
        ({"batch_size": 0}, "batch_size"),
        ({"batch_size": True}, "batch_size"),
        ({"checkpoint_every": 0}, "checkpoint_every"),
        ({"add_only": "best"}, "add_only must be one of"),
        ({"choice": "far"}, "choice must be one of"),
        ({"min_var": -1e-3}, "min_var must be >= 0"),
        ({"var_floor": float("nan")}, "var_floor"),
        ({"sample_steps": 1}, "sample_steps"),
        ({"sample_steps": 3.5}, "sample_steps"),
    ],
)
def test_bad_settings_are_named(kw, msg):
    with pytest.raises(ValueError, match=msg):
        LoopSettings(**{"num_envs": 10, **kw})


def test_integers_are_stored_as_int_and_the_steps_cover_every_environment():
    s = LoopSettings(num_envs=10.0, batch_size=4, checkpoint_every=2.0)
    assert type(s.num_envs) is int and type(s.checkpoint_every) is int
    assert s.num_steps == 3  # 4 + 4 + 2
    assert [k for k in range(1, 4) if s.is_checkpoint_step(k)] == [2, 3]  # every 2nd and the last
    assert (
        LoopSettings(num_envs=0).num_steps == 0
        and LoopSettings(num_envs=8, batch_size=8).num_steps == 1
    )
    assert "success" in ADD_ONLY and "nearest" in CHOICES
    with pytest.raises(AttributeError):
        s.seed = 1  # frozen


def test_step_seeds_depend_on_seed_and_step_only():
    a, b = LoopSettings(num_envs=5, seed=7), LoopSettings(num_envs=50, batch_size=3, seed=7)
    seeds = [a.step_seed(k) for k in range(1, 200)]
    assert seeds == [b.step_seed(k) for k in range(1, 200)]  # other settings do not change them
    assert len(set(seeds)) == len(seeds) and all(0 <= x < 2**63 - 1 for x in seeds)
    assert LoopSettings(num_envs=5, seed=8).step_seed(1) != a.step_seed(1)
