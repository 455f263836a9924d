"""``torch_threads``: the number inside the block, the old one restored after it (also on error)."""

from __future__ import annotations

import pytest
import torch

from protorch.threads import torch_threads


def test_sets_and_restores_threads_even_when_the_block_raises():
    before = torch.get_num_threads()
    with torch_threads(1) as n:
        assert n == 1 and torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError):
        with torch_threads(1):
            raise RuntimeError("boom")
    assert torch.get_num_threads() == before


def test_none_leaves_torch_alone_and_bad_values_are_refused():
    before = torch.get_num_threads()
    with torch_threads(None) as n:
        assert n == before == torch.get_num_threads()
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            with torch_threads(bad):
                pass
    assert torch.get_num_threads() == before
