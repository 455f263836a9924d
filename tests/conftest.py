"""Shared fixtures: seeded random sources, so every test is reproducible on its own, and one torch
thread."""

import numpy as np
import pytest
import torch

# Torch at one thread for the whole session: the tests' operations are small, where a thread pool
# costs more than it gives, and on a machine shared with other work the pool's threads wait for a
# free core at every operation (a batched inverse of 7x7 matrices then takes ~50 ms instead of
# ~1 ms). Tests of the thread settings set their own numbers; subprocesses choose their own.
torch.set_num_threads(1)


@pytest.fixture
def gen() -> torch.Generator:
    """A seeded torch generator (CPU)."""
    return torch.Generator().manual_seed(0)


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded numpy generator, for reference computations independent of torch."""
    return np.random.default_rng(0)


@pytest.fixture
def one_thread():
    """Torch at one thread for the test (restored after): many small iterations gain nothing from
    a thread pool, and pycma's numpy and torch's pools otherwise fight over the cores."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
