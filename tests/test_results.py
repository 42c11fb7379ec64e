"""orchestration/results.py: the one JSON sanitiser and the one result container."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration.results import Result, json_safe


def test_json_safe_gives_strict_json_of_numpy_paths_and_non_finite_floats():
    data = {1: (np.float32(0.5), np.int64(3), np.bool_(True)), "a": np.array([[1.0, np.nan]]),
            "p": Path("/x/y"), "inf": [math.inf, -np.inf], "nan": float("nan")}
    out = json_safe(data)
    assert json.loads(json.dumps(out, allow_nan=False)) == {
        "1": [0.5, 3, True], "a": [[1.0, None]], "p": "/x/y", "inf": ["inf", "-inf"], "nan": None}
    assert type(out["1"][1]) is int and type(out["1"][2]) is bool


def test_result_gives_vectors_in_index_order_columns_and_scalars():
    columns = ["c.p[10]", "c.p[2]", "c.s", "c.p[1]", "c.q[x]"]
    data = np.arange(10.0).reshape(2, 5)
    r = Result(None, np.array([0.0, 0.1]), columns, data)
    assert_allclose(r["c.p"], data[:, [3, 1, 0]])          # numeric, not text, order: 1, 2, 10
    assert_allclose(r["c.p[2]"], data[:, 1])
    assert_allclose(r["c.s"], data[:, 2])
    assert_allclose(r["time"], [0.0, 0.1])
    assert "c.p" in r and "c.q" not in r and "c.p[3]" not in r   # "[x]" is no index
    assert r.variables() == ["c.p", "c.s", "c.q"]
    with pytest.raises(KeyError, match="'c.r' was not recorded"):
        r["c.r"]
    assert r.out_dir is None and math.isnan(r.wall_time) and r.status == "ok"
