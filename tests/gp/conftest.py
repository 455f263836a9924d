import pytest

from .reference import BACKENDS


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every contract test runs on each GP backend."""
    return request.param
