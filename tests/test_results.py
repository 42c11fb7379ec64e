"""orchestration/results.py: the one JSON sanitiser and the one result container."""
import json
import math
from pathlib import Path

import numpy as np

from orchestration.results import json_safe


def test_json_safe_gives_strict_json_of_numpy_paths_and_non_finite_floats():
    data = {1: (np.float32(0.5), np.int64(3), np.bool_(True)), "a": np.array([[1.0, np.nan]]),
            "p": Path("/x/y"), "inf": [math.inf, -np.inf], "nan": float("nan")}
    out = json_safe(data)
    assert json.loads(json.dumps(out, allow_nan=False)) == {
        "1": [0.5, 3, True], "a": [[1.0, None]], "p": "/x/y", "inf": ["inf", "-inf"], "nan": None}
    assert type(out["1"][1]) is int and type(out["1"][2]) is bool
