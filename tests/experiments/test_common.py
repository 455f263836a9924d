import json

import pytest

from protorch.experiments.common import write_json


def _strict_load(path):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_write_json_writes_undefined_metrics_as_null(tmp_path):
    path = tmp_path / "metrics.json"
    write_json(
        path,
        {
            "rate": float("nan"),
            "nested": {"up": float("inf"), "ok": 0.5},
            "list": [1.0, float("-inf")],
        },
    )
    data = _strict_load(path)  # parses as standard JSON
    assert data == {"rate": None, "nested": {"up": None, "ok": 0.5}, "list": [1.0, None]}
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]  # no temp file left


def test_write_json_refuses_unserialisable_data_before_touching_the_file(tmp_path):
    path = tmp_path / "metrics.json"
    write_json(path, {"a": 1})
    with pytest.raises(TypeError):
        write_json(path, {"a": object()})
    assert _strict_load(path) == {"a": 1}  # the previous complete file is still there
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]
