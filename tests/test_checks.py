"""protorch.checks.all_finite: finiteness from the extremes, for every layout and dtype."""

from __future__ import annotations

import pytest
import torch

from protorch.checks import all_finite, check_tensor


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32, torch.float64])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_single_non_finite_value_anywhere_is_found(dtype, bad):
    x = torch.randn(6, 5, 4).to(dtype)
    assert (
        all_finite(x)
        and all_finite(x.transpose(0, 2))
        and all_finite(x[:, ::2])
        and all_finite(x[:0])
    )
    for idx in [(0, 0, 0), (5, 4, 3), (2, 3, 1)]:
        y = x.clone()
        y[idx] = bad
        assert not all_finite(y) and not all_finite(y.transpose(0, 2))  # contiguous and permuted
        assert all_finite(y[:, :3, :1]) == (
            idx[1] >= 3 or idx[2] >= 1
        )  # a strided view sees only its part
        assert not all_finite(y[idx[0] : idx[0] + 1].expand(3, 5, 4))  # a broadcast view


def test_check_tensor_names_nan_and_inf():
    with pytest.raises(ValueError, match="w contains NaN values"):
        check_tensor(torch.tensor([1.0, float("nan"), float("inf")]), "w")
    with pytest.raises(ValueError, match="w contains inf values"):
        check_tensor(torch.tensor([[1.0, 2.0], [3.0, -float("inf")]]).T, "w")
    assert check_tensor([1, 2], "w").dtype == torch.int64  # integers: nothing to check
