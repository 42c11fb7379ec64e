"""LogReplay: a recorded log as outputs (fmus/robot_plant/log_replay_model.py and _fmu.py)."""
from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.estimator_contract import TRUTH
from fmus.common.parameters import ParameterError
from fmus.robot_plant.log_replay_fmu import SIGNALS
from fmus.robot_plant.log_replay_model import LogReplayParameters, RecordedLog, read_columns
from orchestration.master import RunError, run
from orchestration.results import Result
from orchestration.roles import LOG_TRUTH, HonestSignalWarning
from orchestration.scenario import load_scenario

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

SCENARIOS = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios"
OUTPUTS = {s.name: (s.size, s.unit) for s in SIGNALS}


def _csv(tmp_path: Path, text: str, name: str = "log.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _log(path: Path, columns: str, stamp: str | None = None, **kw) -> RecordedLog:
    kw.setdefault("max_gap", 0.5)
    return RecordedLog(LogReplayParameters(log_file=str(path), columns=columns, **kw), OUTPUTS, stamp)


RAMP = "t,a,b,stamp\n0.0,0.0,10.0,0.0\n0.1,1.0,20.0,0.1\n0.2,2.0,30.0,0.2\n"


def test_hold_gives_the_newest_row_and_its_time(tmp_path: Path) -> None:
    log = _log(_csv(tmp_path, RAMP), "q_m_meas[1] = a; q_m_meas[2] = b", time_column="t")
    for t, row in ((0.0, 0), (0.05, 0), (0.1, 1), (0.1 - 1e-12, 1), (0.199, 1), (0.2, 2)):
        values, stamp = log.sample(t)
        assert_array_equal(values, [[0.0, 10.0], [1.0, 20.0], [2.0, 30.0]][row])
        assert stamp == [0.0, 0.1, 0.2][row]


def test_linear_interpolates_and_stands_for_now(tmp_path: Path) -> None:
    log = _log(_csv(tmp_path, RAMP), "q_m_meas[1] = a; q_m_meas[2] = b", time_column="t",
               interpolation="linear")
    for t in (0.0, 0.03, 0.1, 0.17, 0.2):
        values, stamp = log.sample(t)
        assert_allclose(values, [10 * t, 10.0 + 100 * t], rtol=1e-12, atol=1e-12)
        assert stamp == t


def test_time_offset_shifts_the_log(tmp_path: Path) -> None:
    log = _log(_csv(tmp_path, RAMP), "q_m_meas[1] = a; q_m_meas[2] = b", time_column="t", time_offset=0.1)
    values, stamp = log.sample(0.0)          # log time 0.1
    assert_array_equal(values, [1.0, 20.0])
    assert stamp == 0.0
    with pytest.raises(ParameterError, match=r"outside the log .* 'time_offset'"):
        log.sample(0.15)


def test_a_mapped_stamp_column_gives_the_sample_time(tmp_path: Path) -> None:
    path = _csv(tmp_path, "time,a,b,stamp\n10.0,1,2,9.9995\n10.001,3,4,10.0005\n")
    log = _log(path, "q_m_meas[1] = a; t_meas = stamp", time_offset=10.0, stamp="t_meas")
    values, taken = log.sample(0.0005)
    assert values[0] == 1.0 and taken == pytest.approx(-0.0005, abs=1e-12)   # stamp - offset
    assert log.sample(0.001)[1] == pytest.approx(0.0005, abs=1e-12)
    with pytest.raises(ParameterError, match="'t_meas' is mapped, but with interpolation = 'linear'"):
        _log(path, "t_meas = stamp", interpolation="linear", stamp="t_meas")


def test_units_are_converted_to_si(tmp_path: Path) -> None:
    path = _csv(tmp_path, "time,e1,e2,ax\n0,90,-180,1\n0.001,45,0,-0.5\n")
    log = _log(path, "q_m_meas[1] = e1 [deg]; q_m_meas[2] = e2 [deg]\n acc_s[1] = ax [g]")
    values, _ = log.sample(0.0)
    assert_allclose(values, [math.pi / 2, -math.pi, 9.80665], rtol=1e-15)
    named = _log(_csv(tmp_path, "time,ax [g]\n0,1\n0.001,2\n", "named.csv"), "acc_s[1] = ax [g] [g]; "
                 "acc_s[2] = ax [g]")                  # a unit in the header is part of the name
    assert_allclose(named.sample(0.0)[0], [9.80665, 1.0])
    with pytest.raises(ParameterError, match=r"unit 'mm' of column 'e1' cannot be converted to the "
                                             r"unit rad of 'q_m_meas\[1\]'"):
        _log(path, "q_m_meas[1] = e1 [mm]")


def test_a_whole_vector_maps_to_indexed_columns(tmp_path: Path) -> None:
    path = _csv(tmp_path, '"time","enc.q[1]","enc.q[2]"\n0,1,2\n0.001,3,4\n')
    log = _log(path, "q_m_meas = enc.q")
    assert [m.output for m in log.mappings] == ["q_m_meas[1]", "q_m_meas[2]"]
    assert_array_equal(log.sample(0.001)[0], [3.0, 4.0])


@pytest.mark.parametrize("text, columns, match", [
    ("time,a\n0,1\n0.001,2\n", "q_m_meas[1] = nope",
     r"log '.*log.csv': column 'nope' \(for 'q_m_meas\[1\]'\) is not in the log \(columns: time, a\)"),
    ("time,a\n0,1\n0.002,2\n0.001,3\n", "phi_fk = a",
     r"time is not increasing at row 3: time = 0.001 after 0.002 in row 2"),
    ("time,a\n0,1\n0.001,2\n0.5,3\n", "phi_fk = a",
     r"a gap of 0.499 s between rows 2 and 3 \(time 0.001 -> 0.5\) exceeds the parameter max_gap = 0.05 s"),
    ("time,a\n0,1\n0.001,\n0.002,3\n", "phi_fk = a",
     r"row 2 \(line 3\): column 'a' is '', not a number \(a gap in the data\)"),
    ("time,a\n0,1\n0.001,nan\n", "phi_fk = a", r"row 2: column 'a' is nan \(a gap in the data\)"),
    ("t,a\n0,1\n0.001,2\n", "phi_fk = a", r"the time column 'time' is not in the log"),
    ("time,a\n0,1\n0.001,2\n", "p_hat = a", r"'p_hat' is not an output of LogReplay"),
    ("time,a\n0,1\n0.001,2\n", "acc_s = a", r"'acc_s' is a vector of 3 and 'a' one column"),
    ("time,a\n0,1\n0.001,2\n", "phi_fk = a; phi_fk = a", r"'phi_fk' is mapped twice"),
])
def test_bad_logs_name_file_column_and_row(tmp_path: Path, text: str, columns: str, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        _log(_csv(tmp_path, text), columns, max_gap=0.05)


def test_hdf5_reads_as_csv(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    csv_path = _csv(tmp_path, RAMP)
    with h5py.File(tmp_path / "log.h5", "w") as f:
        f["t"] = [0.0, 0.1, 0.2]
        f["enc/a"] = [0.0, 1.0, 2.0]
        f["enc/b"] = [10.0, 20.0, 30.0]
    a = _log(csv_path, "q_m_meas[1] = a; q_m_meas[2] = b", time_column="t")
    b = _log(tmp_path / "log.h5", "q_m_meas[1] = enc/a; q_m_meas[2] = enc/b", time_column="t")
    assert_array_equal(a.values, b.values)
    assert_array_equal(a.times, b.times)


def test_hdf5_without_h5py_is_a_clear_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "h5py", None)         # import h5py raises ImportError
    (tmp_path / "log.h5").write_bytes(b"")
    with pytest.raises(ParameterError, match=r"reading HDF5 needs the package h5py.*flexfusion\[replay\]"):
        read_columns(tmp_path / "log.h5", ["t"])


@pytest.mark.parametrize("time_data, match", [
    (np.array([b"0", b"1", b"2"]), r"dataset 't' holds \|S1 values, not numbers"),
    (np.zeros(3, dtype=[("a", "f8"), ("b", "i4")]), r"dataset 't' holds \[\('a', '<f8'\), .* values, not numbers"),
    (np.arange(3.0) + 0j, r"dataset 't' holds complex128 values, not numbers"),
    (np.array([False, True, True]), r"dataset 't' holds bool values, not numbers"),
])
def test_an_hdf5_dataset_of_another_type_is_named(tmp_path: Path, time_data: np.ndarray, match: str) -> None:
    """Text, compound, complex or boolean data was a ValueError, a TypeError or silently cast."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "log.h5", "w") as f:
        f["t"] = time_data
        f["a"] = [0.0, 1.0, 2.0]
    with pytest.raises(ParameterError, match=rf"log '.*log.h5': {match} \(float or integer\)"):
        _log(tmp_path / "log.h5", "phi_fk = a", time_column="t", max_gap=5.0)


@pytest.mark.parametrize("name, content, match", [
    ("log.h5", bytes(range(256)) * 8, r"not a readable HDF5 file \(.*file signature not found"),
    ("log.h5", b"", r"not a readable HDF5 file"),
    ("log.csv", bytes(range(128, 256)) * 8, r"not a CSV file of UTF-8 text \(near line 1: invalid start byte\)"),
    ("log.csv", b"time,a\n0," + b"9" * 200_000 + b"\n", r"line 2: not CSV: field larger than field limit"),
])
def test_a_file_that_is_not_a_log_is_named(tmp_path: Path, name: str, content: bytes, match: str) -> None:
    """A binary file (as HDF5 or CSV) or an oversized CSV field was an OSError, a
    UnicodeDecodeError or a csv.Error."""
    pytest.importorskip("h5py")
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ParameterError, match=rf"log '.*{name}': {match}"):
        _log(tmp_path / name, "phi_fk = a")


# ---- through the master -------------------------------------------------------------------

@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Result:
    """The recording scenario, 1 s: the log and the live estimates."""
    return run(SCENARIOS / "replay_record.toml", ["scenario.stop_time=1.0"],
               out_dir=tmp_path_factory.mktemp("live"))


def test_a_replayed_log_reproduces_the_live_estimates_bit_for_bit(live: Result, tmp_path: Path) -> None:
    replay = run(SCENARIOS / "replay_log.toml",
                 ["scenario.stop_time=1.0", f"log.log_file={str(live.out_dir / 'results.csv')!r}"],
                 out_dir=tmp_path)
    assert_array_equal(replay.time, live.time)
    for estimate in ("rigid.p_tool_hat", "ekf.p_tool_hat"):
        assert_array_equal(replay[estimate], live[estimate], err_msg=estimate)
    assert_array_equal(replay["log.p_tool"], live["plant.p_tool"])     # the truth, replayed
    assert replay.against["ekf_position_rmse"] == "log"


def test_an_hdf5_log_replays_as_its_csv(live: Result, tmp_path: Path) -> None:
    """The same log as HDF5 (one dataset per column, h5py inside the FMU) gives the same bits."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "log.h5", "w") as f:
        f["time"] = live.time
        for j, name in enumerate(live.columns):
            f[name] = live.data[:, j]
    replay = run(SCENARIOS / "replay_log.toml",
                 ["scenario.stop_time=1.0", f"log.log_file={str(tmp_path / 'log.h5')!r}"],
                 out_dir=tmp_path / "r")
    assert_array_equal(replay["ekf.p_tool_hat"], live["ekf.p_tool_hat"])


def test_hold_at_half_the_recording_rate_is_not_the_live_run(live: Result, tmp_path: Path) -> None:
    """The comparison above can fail: the log thinned to every other row (a 500 Hz log, held)
    gives other estimates."""
    lines = (live.out_dir / "results.csv").read_text().splitlines()
    thinned = _csv(tmp_path, "\n".join(lines[:1] + lines[1::2]) + "\n")
    replay = run(SCENARIOS / "replay_log.toml",
                 ["scenario.stop_time=1.0", f"log.log_file={str(thinned)!r}"], out_dir=tmp_path / "r")
    assert not np.array_equal(replay["ekf.p_tool_hat"], live["ekf.p_tool_hat"])
    assert_allclose(replay["ekf.p_tool_hat"], live["ekf.p_tool_hat"], atol=1e-3)   # still tracks


def test_a_missing_column_stops_the_run_naming_it(live: Result, tmp_path: Path) -> None:
    with pytest.raises(RunError, match=r"component 'log'.*column 'imu.acc\[1\]' \(for 'acc_s\[1\]'\) "
                                       r"is not in the log"):
        run(SCENARIOS / "replay_log.toml",
            ["scenario.stop_time=0.6", f"log.log_file={str(live.out_dir / 'results.csv')!r}",
             'log.columns="q_m_meas = encoder.q_m_meas; acc_s = imu.acc; '
             'dddq_a_ref = controller.dddq_a_ref; p_tool = plant.p_tool; q_a = plant.q_a"'],
            out_dir=tmp_path)


def test_a_binary_file_as_the_log_stops_the_run_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "log.h5").write_bytes(bytes(range(256)) * 8)
    with pytest.raises(RunError, match=r"component 'log'.*log '.*log.h5': not a readable HDF5 file") as info:
        run(SCENARIOS / "replay_log.toml", ["scenario.stop_time=0.6", f"log.log_file={str(tmp_path / 'log.h5')!r}"],
            out_dir=tmp_path / "out")
    assert "\n" not in str(info.value) and "Traceback" not in str(info.value)


def test_an_unmapped_output_that_is_read_stops_the_run_naming_it(tmp_path: Path) -> None:
    with pytest.raises(RunError, match=r"output 'acc_s\[1\]' is read .* but no log column feeds it"):
        run(SCENARIOS / "replay_log.toml",
            ["scenario.stop_time=0.6", 'log.columns="q_m_meas = encoder.q_m_meas; '
             'dddq_a_ref = controller.dddq_a_ref; p_tool = plant.p_tool; q_a = plant.q_a"'],
            out_dir=tmp_path)


def test_the_shipped_example_runs_the_estimators_on_the_log(tmp_path: Path) -> None:
    r = run(SCENARIOS / "replay_log.toml", out_dir=tmp_path)
    assert len(r.time) == 2001
    # the EKF (motor angles and accelerometer) beats rigid kinematics on the replayed robot
    assert r.metrics["ekf_position_rmse"] < r.metrics["rigid_position_rmse"] < 1e-3
    # consistency metrics in metrics.json, with their degrees of freedom and 95 % band
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["ekf_nis"]["dof"] == 4 and saved["ekf_nis"]["against"] == "innovations"
    assert saved["ekf_angle_nees"]["dof"] == 2 and saved["ekf_angle_nees"]["covariance"] == "ekf.P_x"
    # dimensionless (an error normalised by its covariance), not the estimate's rad
    assert {e["unit"] for n, e in saved.items() if e["kind"] in ("nees", "nis")} == {"1"}
    assert saved["ekf_angle_nees"]["band_95"] == pytest.approx([0.0506, 7.378], rel=1e-3)
    assert 0.0 <= r.metrics["ekf_nis_in_band"] <= 1.0 and r.metrics["ekf_nis"] > 0.0


def test_the_log_truth_feeding_an_estimator_is_an_oracle(tmp_path: Path) -> None:
    doc = f"""
connections = ["log.p_tool -> cf.p_fk", "log.acc_s -> cf.acc_s"]
[scenario]
stop_time = 0.01
base_step = 0.001
[components.log]
fmu = "LogReplay"
[components.cf]
fmu = "ComplementaryFilter"
"""
    (tmp_path / "s.toml").write_text(doc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_scenario(tmp_path / "s.toml")
    texts = [str(w.message) for w in caught if issubclass(w.category, HonestSignalWarning)]
    assert len(texts) == 1 and "log.p_tool -> cf.p_fk" in texts[0]
    assert LOG_TRUTH == {s.name for s in TRUTH}
