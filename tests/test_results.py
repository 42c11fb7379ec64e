"""orchestration/results.py directly: the streaming CSV (bit-exact round trip, fmpy reads it,
rows on disk before the run ends), ``name[i]`` lookup in :class:`Result`, the run folder's JSON
files and :meth:`Result.load`."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from fmpy.util import read_csv
from numpy.testing import assert_allclose, assert_array_equal

from orchestration.results import (CSV_NAME, METRICS_NAME, RUN_NAME, CsvWriter, Result, ResultWarning,
                                   json_safe, read_results_csv, versions, write_json)

COLUMNS = ["plant.q[1]", "plant.q[2]", "plant.q[10]", "ekf.trace_p", "plant.qq[1]"]


def awkward_rows(n: int = 7) -> np.ndarray:
    """Values whose decimal form is not short: random doubles, tiny, huge, -0.0, inf, nan."""
    rows = np.random.default_rng(1).standard_normal((n, 1 + len(COLUMNS))) * 10.0 ** np.arange(-300, 300, 100)[:6]
    rows[:, 0] = np.arange(n) * 0.001
    rows[1, 1:4] = [-0.0, 5e-324, 1.7976931348623157e308]
    rows[2, 1:3] = [math.inf, -math.inf]
    rows[3, 4] = math.nan
    return rows


def write(tmp_path, rows: np.ndarray, columns=COLUMNS, **kw) -> None:  # noqa: ANN001
    with CsvWriter(tmp_path / CSV_NAME, columns, **kw) as w:
        for r in rows:
            w(r[0], r[1:])


def test_csv_round_trip_is_bit_exact(tmp_path) -> None:
    rows = awkward_rows()
    write(tmp_path, rows)
    names, data, torn = read_results_csv(tmp_path / CSV_NAME)
    assert names == COLUMNS and not torn
    assert_array_equal(data, rows)                          # nan == nan here
    assert np.signbit(data[1, 1])                           # -0.0 kept
    assert (tmp_path / CSV_NAME).read_text().splitlines()[0] == \
        '"time","plant.q[1]","plant.q[2]","plant.q[10]","ekf.trace_p","plant.qq[1]"'


def test_fmpy_reads_the_csv_with_the_scalar_names(tmp_path) -> None:
    rows = awkward_rows()
    write(tmp_path, rows)
    table = read_csv(str(tmp_path / CSV_NAME))
    assert list(table.dtype.names) == ["time", *COLUMNS]
    assert_array_equal(table["plant.q[10]"], rows[:, 3])


def test_rows_reach_the_disk_as_the_run_goes(tmp_path) -> None:
    w = CsvWriter(tmp_path / CSV_NAME, ["a.x"], flush_every=3)
    for k in range(4):
        w(k * 0.1, np.array([float(k)]))
    on_disk = (tmp_path / CSV_NAME).read_text().splitlines()
    assert len(on_disk) == 1 + 3                            # flushed after the 3rd row
    w.close()
    assert len((tmp_path / CSV_NAME).read_text().splitlines()) == 1 + 4


def test_a_column_name_that_would_break_the_csv_is_refused(tmp_path) -> None:
    for bad in ("a,b", 'a"b'):
        with pytest.raises(ValueError, match="must not contain"):
            CsvWriter(tmp_path / CSV_NAME, [bad])


@pytest.mark.filterwarnings("ignore:loadtxt")   # read_results_csv lets numpy warn on a header-only file
def test_empty_run_and_no_columns(tmp_path) -> None:
    write(tmp_path, np.zeros((0, 1 + len(COLUMNS))))
    names, data, _ = read_results_csv(tmp_path / CSV_NAME)
    assert names == COLUMNS and data.shape == (0, 1 + len(COLUMNS))
    write(tmp_path, np.array([[0.0], [0.5]]), columns=[])
    assert_array_equal(read_results_csv(tmp_path / CSV_NAME)[1], [[0.0], [0.5]])


def result(rows: np.ndarray) -> Result:
    return Result(out_dir=None, time=rows[:, 0], columns=COLUMNS, data=rows[:, 1:])


def test_name_i_lookup_orders_by_index_and_needs_the_exact_base() -> None:
    rows = awkward_rows()
    r = result(rows)
    assert_array_equal(r["plant.q"], rows[:, [1, 2, 3]])      # q[1], q[2], q[10]: numeric order
    assert_array_equal(r["plant.q[10]"], rows[:, 3])
    assert_array_equal(r["plant.qq"], rows[:, [5]])           # 'plant.q' does not take qq[1]
    assert_array_equal(r["ekf.trace_p"], rows[:, 4])          # a scalar: (n,)
    assert_array_equal(r["time"], rows[:, 0])
    assert r.variables() == ["plant.q", "ekf.trace_p", "plant.qq"]
    assert "plant.q" in r and "plant.q[3]" not in r and "plant" not in r
    with pytest.raises(KeyError, match="'plant.p' was not recorded .*plant.q, ekf.trace_p"):
        r["plant.p"]


def test_write_json_makes_non_finite_numbers_json(tmp_path) -> None:
    write_json(tmp_path / "m.json", {"a": math.nan, "b": [math.inf, -math.inf, 1.5], 3: {"p": tmp_path}})
    assert json.loads((tmp_path / "m.json").read_text()) == \
        {"a": None, "b": ["inf", "-inf", 1.5], "3": {"p": str(tmp_path)}}


def test_load_reads_a_run_folder(tmp_path) -> None:
    rows = awkward_rows()
    write(tmp_path, rows)
    write_json(tmp_path / METRICS_NAME, {"ekf_rmse": {"value": 1e-4, "kind": "rmse", "estimate": "ekf.p",
                                                      "truth": "plant.p", "against": "truth"},
                                         "old_style": 2.0})
    write_json(tmp_path / RUN_NAME, {"status": "error", "error": "ekf: diverged at t = 0.004 s",
                                     "warnings": ["w"]})              # the old name of "failed"
    with pytest.warns(ResultWarning, match="failed"):
        r = Result.load(tmp_path)
    assert_array_equal(r.time, rows[:, 0])
    assert_array_equal(r["plant.q"], rows[:, 1:4])
    assert r.metrics == {"ekf_rmse": 1e-4, "old_style": 2.0}
    assert r.against == {"ekf_rmse": "truth"}
    assert (r.status, r.error, r.warnings) == ("failed", "ekf: diverged at t = 0.004 s", ["w"])
    assert r.units == {} and r.metric_units == {"ekf_rmse": ""}     # a run.json from before units
    units = {"time": "s", **{c: "rad" for c in COLUMNS}}
    write_json(tmp_path / RUN_NAME, {"status": "ok", "rows": len(rows), "units": units})
    assert Result.load(tmp_path).units == units
    with pytest.raises(FileNotFoundError, match="not a run folder"):
        Result.load(tmp_path / "nowhere")


def test_versions_name_the_packages_a_run_depends_on() -> None:
    v = versions()
    assert {"python", "fmpy", "pythonfmu", "numpy", "scipy", "flexfusion"} <= set(v)
    assert v["numpy"] == np.__version__


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
