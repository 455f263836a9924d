"""The package's top level: every optimiser exported, and one base for protorch's own errors."""

from __future__ import annotations

import pytest

import protorch
from protorch.data.files import CheckpointError
from protorch.errors import ProtorchError
from protorch.experiments.settings import SettingsError
from protorch.optim import OPTIMIZERS
from protorch.robots.loader import RobotError
from protorch.sim.mj import MujocoMissing
from protorch.tasks.base import TaskContractError


def test_every_registered_optimiser_is_exported_at_the_top():
    for cls in OPTIMIZERS.values():
        assert getattr(protorch, cls.__name__) is cls, cls.__name__
        assert cls.__name__ in protorch.__all__
    assert {"EPRO", "CEM", "CMAES", "PRO", "RWR", "RWPO"} <= set(protorch.__all__)
    assert all(hasattr(protorch, name) for name in protorch.__all__)


@pytest.mark.parametrize(
    "cls, builtin",
    [
        (TaskContractError, (TypeError, ValueError)),
        (MujocoMissing, (ImportError,)),
        (SettingsError, (ValueError,)),
        (CheckpointError, (ValueError,)),
        (RobotError, (ValueError,)),
    ],
)
def test_each_error_is_a_protorch_error_and_keeps_its_builtin_base(cls, builtin):
    assert issubclass(cls, ProtorchError) and protorch.ProtorchError is ProtorchError
    for base in builtin:
        with pytest.raises(base):  # callers catching the builtin still catch it
            raise cls("x")
    with pytest.raises(ProtorchError):
        raise cls("x")


def test_a_bad_robot_raises_a_protorch_error(tmp_path):
    from protorch.robots import load_robot

    bad = tmp_path / "arm.urdf"
    bad.write_text("<robot name='x'><link")  # does not parse
    with pytest.raises(ProtorchError, match="arm.urdf"):
        load_robot({"urdf": str(bad), "end_link": "tool0", "home": [0.0] * 7})
