"""The ``>>>`` examples of the core public API run as written (``doctest`` on each module)."""

from __future__ import annotations

import doctest
import importlib

import pytest
import torch

MODULES = [
    "protorch.primitives.promp",
    "protorch.optim.pro",
    "protorch.optim.efficient_pro",
    "protorch.optim.rwr",
    "protorch.optim.rwpo",
    "protorch.optim.cem",
    "protorch.optim.cmaes",
    "protorch.gp",
    "protorch.gp.closed_form",
    "protorch.gp.gpytorch_exact",
    "protorch.gp.sparse",
    "protorch.loop.initial",
]


@pytest.mark.parametrize("name", MODULES)
def test_the_modules_examples_run(name):
    module = importlib.import_module(name)
    torch.manual_seed(0)  # examples that draw from torch's global generator
    result = doctest.testmod(module, extraglobs={"torch": torch}, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0, f"{name} has no >>> example"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"
