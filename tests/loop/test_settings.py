"""LoopSettings, OptimizerSpec and Run: validation before any work, the number of steps, the
per-step seed, the forms self_improve takes, and the app's loop schema generated from
LoopSettings."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import pytest
import torch

from protorch import PRO, RWR, make_env_map
from protorch.experiments.settings import Loop, SettingsError, validate
from protorch.loop import ADD_ONLY, CHOICES, LoopSettings, OptimizerSpec, Run, self_improve
from protorch.loop.settings import LOOP_GROUP


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
        ({"refill": "maybe"}, "refill must be auto, true or false"),
        ({"refill": 1}, "refill must be auto, true or false"),
        ({"eval_dtype": "float16"}, "eval_dtype must be one of"),
        ({"threads": "many"}, "threads must be"),
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


def test_eval_dtype_is_stored_by_name_and_read_as_a_torch_dtype():
    s = LoopSettings(eval_dtype=torch.float64)
    assert s.eval_dtype == "float64" and s.torch_eval_dtype is torch.float64
    assert LoopSettings(eval_dtype=None).torch_eval_dtype is None
    assert LoopSettings().replace(batch_size=1).batch_size == 1


def test_the_optimizer_spec_takes_a_class_a_partial_or_a_spec():
    spec = OptimizerSpec(PRO, {"beta": 2.0})
    assert OptimizerSpec.of(spec) is spec
    assert OptimizerSpec.of(RWR) == OptimizerSpec(RWR, {})
    assert OptimizerSpec.of(functools.partial(PRO, beta=2.0)) == spec
    with pytest.raises(ValueError, match="seed"):
        OptimizerSpec(PRO, {"seed": 1})
    with pytest.raises(TypeError, match="optimiser class"):
        OptimizerSpec.of("pro")


def test_the_run_takes_a_run_a_folder_or_none():
    assert Run.of(None) == Run() and Run.of("runs/x").dir == "runs/x"
    assert Run.of(Path("runs/x")).dir == Path("runs/x")
    with pytest.raises(ValueError, match="needs a dir"):
        Run(resume=True)
    with pytest.raises(TypeError, match="a Run, a folder or None"):
        Run.of(3)


def test_the_old_keyword_form_names_the_new_one():
    with pytest.raises(
        TypeError, match=r"no longer takes num_envs=, optimizer_kwargs=.*LoopSettings"
    ):
        self_improve(
            None,
            None,
            None,
            PRO,
            lambda: make_env_map("torch", 1.0),
            num_envs=3,
            optimizer_kwargs={},
        )


def test_the_apps_loop_schema_is_generated_from_loop_settings():
    fields = {f.name: f for f in dataclasses.fields(LoopSettings)}
    schema = {f.name: f for f in dataclasses.fields(Loop)}
    assert tuple(schema) == LOOP_GROUP
    for name, f in schema.items():
        assert f.default == fields[name].default and f.metadata == fields[name].metadata
    validate(Loop, {"num_envs": 0, "eval_dtype": None, "refill": "auto"}, "settings.loop")
    for bad, msg in (
        ({"refill": "maybe"}, "settings.loop.refill='maybe' must be true or false or one of auto"),
        ({"eval_dtype": "float16"}, "must be one of float32, float64 or null"),
    ):
        with pytest.raises(SettingsError, match=msg):
            validate(Loop, bad, "settings.loop")
