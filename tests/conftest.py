"""Shared fixtures: seeded random sources, so every test is reproducible on its own."""

import numpy as np
import pytest
import torch


@pytest.fixture
def gen() -> torch.Generator:
    """A seeded torch generator (CPU)."""
    return torch.Generator().manual_seed(0)


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded numpy generator, for reference computations independent of torch."""
    return np.random.default_rng(0)
