"""Forking runs (orchestration/fork.py): a run from a saved state equals the uninterrupted one."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from orchestration import fork
from orchestration.cli import main
from orchestration.results import Result
from orchestration.scenario import ScenarioError, scenario_document
from orchestration.study import open_executor

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

SCENARIO = Path(__file__).resolve().parent.parent / "orchestration" / "scenarios" / "replay_record.toml"
STOP = ["scenario.stop_time=0.6"]
T = 0.237        # not a multiple of the EKF's step: mid-way for a multi-rate part


def _multirate() -> dict:
    """The recording scenario with its EKF at 100 Hz (held between its steps)."""
    doc = scenario_document(SCENARIO)
    doc["components"]["ekf"]["step"] = 0.01
    return doc


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> tuple[Result, Path]:
    """The uninterrupted run (plant, controller, noisy sensors, 2012 EKF at 100 Hz: every
    component with a state of its own, the noise streams included), saving its state at T."""
    d = tmp_path_factory.mktemp("saved")
    result = fork.run_saving(_multirate(), T, d / "state.json", STOP, out_dir=d / "run")
    return result, d / "state.json"


def test_a_forked_run_equals_the_uninterrupted_one(saved, tmp_path: Path) -> None:
    whole, state = saved
    doc = json.loads(state.read_text())
    assert doc["time"] == pytest.approx(T) and set(doc["fmus"]) == {
        "controller", "plant", "encoder", "imu", "rigid", "ekf"}
    first = np.searchsorted(whole.time, T - 1e-9)
    for k in range(2):                   # many runs from one state: each the same
        forked = fork.resume(_multirate(), state, STOP, out_dir=tmp_path / str(k))
        assert forked.columns == whole.columns
        assert_array_equal(forked.time, whole.time[first:])
        assert_array_equal(forked.data, whole.data[first:])


def test_the_fork_can_fail(saved, tmp_path: Path) -> None:
    """Not trivially equal: with the encoder's state of another time (its noise stream and held
    sample) the forked run differs."""
    whole, state = saved
    fork.run_saving(_multirate(), 0.001, tmp_path / "s0.json", STOP, out_dir=tmp_path / "early")
    mixed = json.loads(state.read_text())
    mixed["fmus"]["encoder"] = json.loads((tmp_path / "s0.json").read_text())["fmus"]["encoder"]
    (tmp_path / "mixed.json").write_text(json.dumps(mixed))
    forked = fork.resume(_multirate(), tmp_path / "mixed.json", STOP, out_dir=tmp_path / "mixed")
    first = np.searchsorted(whole.time, T - 1e-9)
    assert not np.array_equal(forked["encoder.q_m_meas"][1:], whole["encoder.q_m_meas"][first + 1:])


def test_a_fork_may_change_stop_time_and_record(saved, tmp_path: Path) -> None:
    whole, state = saved
    doc = _multirate()
    doc["record"]["variables"] = ["plant.p_tool", "ekf.p_tool_hat"]
    forked = fork.resume(doc, state, ["scenario.stop_time=0.4"], out_dir=tmp_path)
    first = np.searchsorted(whole.time, T - 1e-9)
    assert forked.time[-1] == pytest.approx(0.4)
    for name in ("plant.p_tool", "ekf.p_tool_hat"):
        assert_array_equal(forked[name], whole[name][first:first + len(forked.time)])


@pytest.mark.parametrize("overrides, match", [
    (["encoder.noise=1e-4"], r"parameter 'encoder.noise' = 0.0001 differs from the state's \(the FMU's default\), and "
                             r"it is fixed: FMI 2.0 allows a change after initialisation only for a tunable"),
    (["encoder.filter_order=1"], r"parameter 'encoder.filter_order' = 1 .* it is fixed"),
    (["scenario.stop_time=0.2"], r"stop_time 0.2 s is not after the state's time 0.237 s"),
])
def test_a_fork_that_fmi_does_not_allow_is_refused(saved, tmp_path: Path, overrides, match) -> None:
    _, state = saved
    with pytest.raises(ScenarioError, match=match):
        fork.resume(_multirate(), state, STOP + overrides, out_dir=tmp_path)


def test_forks_with_new_seeds_equal_each_other_before_the_state_and_differ_after(saved, tmp_path: Path) -> None:
    """scenario.seed in a fork reseeds every sensor at the state's time (fork.reseed_fork). The
    drive reads its encoder, so the new noise reaches the plant too, by a fraction of a
    micrometre (measured 0.16 um; the sensors' readings change by their noise)."""
    whole, state = saved
    first = np.searchsorted(whole.time, T - 1e-9)
    a, b = (fork.resume(_multirate(), state, STOP + [f"scenario.seed={s}"], out_dir=tmp_path / str(s))
            for s in (5, 6))
    assert_array_equal(a.data[0], whole.data[first])      # at the state's time: the saved values
    assert_array_equal(b.data[0], whole.data[first])
    # the encoder's noise is 0.2 of its quantum: about a quarter of its readings change
    for name, changed in (("encoder.q_m_meas", 0.15), ("imu.acc_s", 0.9), ("ekf.p_tool_hat", 0.9)):
        assert np.mean(a[name][1:] != b[name][1:]) > changed, name
        assert np.mean(a[name][1:] != whole[name][first + 1:]) > changed, name
    gap = np.abs(a["plant.p_tool"] - b["plant.p_tool"]).max()
    assert 0.0 < gap < 1e-6


def test_a_reseeded_fork_is_reproducible_and_reseeds_only_its_sensor(saved, tmp_path: Path) -> None:
    whole, state = saved
    first = np.searchsorted(whole.time, T - 1e-9)
    a, b = (fork.resume(_multirate(), state, STOP + ["encoder.reseed=7"], out_dir=tmp_path / k)
            for k in "ab")
    assert_array_equal(a.data, b.data)
    assert np.mean(a["encoder.q_m_meas"][1:] != whole["encoder.q_m_meas"][first + 1:]) > 0.15
    # the IMU's stream goes on: its readings change only through the plant's sub-micrometre
    # change (the drive reads the encoder; measured RMS 0.0009 m/s^2), far below a reseeded
    # IMU's difference (its noise, 0.02 m/s^2 per reading: RMS 0.029)
    diff = a["imu.acc_s"] - whole["imu.acc_s"][first:]
    assert np.sqrt(np.mean(diff ** 2)) < 0.005


def test_monte_carlo_after_a_common_warm_up(tmp_path: Path) -> None:
    stop = ["scenario.stop_time=0.05"]
    forks = fork.monte_carlo(SCENARIO, 0.02, [3, 4], stop, out_dir=tmp_path)
    warm = Result.load(tmp_path / "warmup")           # the uninterrupted run of the scenario's seed
    for f in forks:
        assert_array_equal(f.time, warm.time[20:])
        assert_array_equal(f.data[0], warm.data[20])
    assert np.mean(forks[0]["imu.acc_s"][1:] != forks[1]["imu.acc_s"][1:]) > 0.9
    again = fork.resume(SCENARIO, tmp_path / "state.json", stop + ["scenario.seed=4"],
                        out_dir=tmp_path / "again")
    assert_array_equal(again.data, forks[1].data)
    assert_array_equal(Result.load(tmp_path / "seed-3").data, forks[0].data)
    with pytest.raises(ScenarioError, match="distinct seeds"):
        fork.monte_carlo(SCENARIO, 0.02, [3, 3], stop, out_dir=tmp_path / "x")


@pytest.mark.parametrize("scheduler", [None, "local"])
def test_forks_in_parallel_equal_the_forks_one_after_the_other(tmp_path: Path, scheduler) -> None:
    """``--forks N`` on the study executor (local processes, a Dask cluster): each fork's
    results are those of the same fork run here, after the others."""
    if scheduler:
        pytest.importorskip("distributed")
    stop = ["scenario.stop_time=0.05"]
    one_by_one = fork.monte_carlo(SCENARIO, 0.02, [3, 4, 5], stop, out_dir=tmp_path / "seq")
    with open_executor(workers=2, scheduler=scheduler) as ex:
        parallel = fork.monte_carlo(SCENARIO, 0.02, [3, 4, 5], stop, out_dir=tmp_path / "par", executor=ex)
    for s, a, b in zip((3, 4, 5), one_by_one, parallel):
        assert b.out_dir == (tmp_path / "par" / f"seed-{s}").resolve()
        assert b.columns == a.columns
        assert_array_equal(b.time, a.time)
        assert_array_equal(b.data, a.data)
        assert_array_equal(Result.load(b.out_dir).data, a.data)
    assert not np.array_equal(parallel[0].data, parallel[1].data)


def test_a_fork_with_another_step_is_refused(saved, tmp_path: Path) -> None:
    _, state = saved
    with pytest.raises(ScenarioError, match=r"component 'ekf': step 0.001 differs from the state's 0.01"):
        fork.resume(SCENARIO, state, STOP, out_dir=tmp_path)


def test_a_state_of_another_scenario_is_refused(saved, tmp_path: Path) -> None:
    _, state = saved
    other = SCENARIO.parent / "replay_log.toml"
    with pytest.raises(ScenarioError, match=r"the components \(log, rigid, ekf\) are not those of the state"):
        fork.resume(other, state, ["scenario.stop_time=0.6"], out_dir=tmp_path)


def test_cli_saves_and_forks(tmp_path: Path, capsys) -> None:
    base = ["run", str(SCENARIO), "--set", "scenario.stop_time=0.05", "--no-progress"]
    assert main(base + ["--out", str(tmp_path / "a"), "--save-state-at", "0.02",
                        "--state-out", str(tmp_path / "s.json")]) == 0
    assert "state at t = 0.02 s in" in capsys.readouterr().out
    assert main(base + ["--out", str(tmp_path / "b"), "--from-state", str(tmp_path / "s.json")]) == 0
    whole = (tmp_path / "a" / "results.csv").read_text().splitlines()
    forked = (tmp_path / "b" / "results.csv").read_text().splitlines()
    assert forked[0] == whole[0] and forked[1:] == whole[21:]        # header; rows from 0.02 s


def test_cli_monte_carlo_after_a_warm_up(tmp_path: Path, capsys) -> None:
    """The forks' rows (run on 2 worker processes), and their metrics' mean and spread over the forks."""
    for name in (SCENARIO.name, "identified_robot.toml"):          # the scenario with a metric
        (tmp_path / name).write_text((SCENARIO.parent / name).read_text())
    with (tmp_path / SCENARIO.name).open("a") as f:
        f.write('\n[[metrics]]\nkind = "rmse"\nname = "ekf_rmse"\nestimate = "ekf.p_tool_hat"\n'
                'truth = "plant.p_tool"\n')
    assert main(["run", str(tmp_path / SCENARIO.name), "--set", "scenario.stop_time=0.03", "--workers", "2",
                 "--no-progress", "--out", str(tmp_path), "--save-state-at", "0.02", "--forks", "2"]) == 0
    out = capsys.readouterr().out
    seed = scenario_document(SCENARIO)["scenario"]["seed"]
    for s in (seed + 1, seed + 2):
        assert f"fork scenario.seed={s}: 11 rows in {tmp_path / f'seed-{s}'}" in out
    a, b = (Result.load(tmp_path / f"seed-{s}") for s in (seed + 1, seed + 2))
    assert_array_equal(a.data[0], b.data[0])
    assert np.mean(a["imu.acc_s"][1:] != b["imu.acc_s"][1:]) > 0.5     # some quantised alike
    rmse = [a.metrics["ekf_rmse"], b.metrics["ekf_rmse"]]
    assert f"ekf_rmse {np.mean(rmse):.6g} +- {np.std(rmse, ddof=1):.2g} m" in " ".join(out.split())


@pytest.mark.parametrize("extra, match", [
    (["--save-state-at", "0.02"], "--save-state-at T and --state-out FILE go together"),
    (["--forks", "2"], "--forks N goes with --save-state-at T"),
    (["--save-state-at", "0.02", "--state-out", "x.json", "--forks", "2"], "not with --state-out"),
    (["--save-state-at", "0.02", "--forks", "0"], "--forks 0: at least one fork"),
    (["--save-state-at", "0.0205", "--state-out", "x.json"], "must be a multiple of the base step"),
    (["--save-state-at", "0.05", "--state-out", "x.json"], "before stop_time"),
    (["--from-state", "nope.json"], "state file not found: nope.json"),
    (["--workers", "2"], "--workers and --scheduler go with --forks N"),
    (["--save-state-at", "0.02", "--forks", "2", "--workers", "0"], "--workers must be at least 1"),
])
def test_cli_fork_errors_exit_2(tmp_path: Path, capsys, monkeypatch, extra, match) -> None:
    monkeypatch.chdir(tmp_path)
    code = main(["run", str(SCENARIO), "--set", "scenario.stop_time=0.05", "--no-progress", *extra])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and match in err and len(err.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def cli_state(tmp_path_factory) -> tuple[Path, dict]:
    """A state file saved by the command line at 0.02 s (stop 0.05 s) and its document."""
    d = tmp_path_factory.mktemp("cli_state")
    assert main(["run", str(SCENARIO), "--set", "scenario.stop_time=0.05", "--no-progress", "--out", str(d / "run"),
                 "--save-state-at", "0.02", "--state-out", str(d / "state.json")]) == 0
    return d / "state.json", json.loads((d / "state.json").read_text())


class _Payload:
    """Unpickling it creates the marker file (what a crafted state.json did: any command)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def _b64(data: bytes) -> str:
    import base64
    return base64.b64encode(data).decode()


@pytest.mark.parametrize("case, match", [
    ("pickle", "component 'encoder' refused its saved state; FMU log: "),
    ("truncated", "component 'imu' refused its saved state; FMU log: "),
    ("other fmu", "component 'encoder' refused its saved state; FMU log: "),
    ("bad base64", "entry 'fmus.encoder' is not base64"),
    ("no values", "entry 'values' is missing"),
    ("no fmu", "entry 'fmus' must hold one state per component"),
    ("string time", "entry 'time' must be a number of seconds > 0, not '0.02'"),
    ("negative step", "entry 'step' must be a base step number > 0, not -20"),
    ("huge step", "entry 'step' must be a base step number > 0, not 1000000000000000000"),
    ("float step", "entry 'step' must be a base step number > 0, not 1e+18"),
    ("other step", "entry 'step' 5 base steps of 0.001 s are not the state's time 0.02 s"),
    ("bad structure", "entry 'structure' must hold base_step"),
    ("not json", "not a FlexFusion state file"),
])
def test_a_bad_or_crafted_state_file_is_one_error_line_and_runs_nothing(cli_state, tmp_path: Path, capsys,
                                                                         case, match) -> None:
    path, doc = cli_state
    doc = json.loads(json.dumps(doc))
    marker = tmp_path / "ran"
    fmus = doc["fmus"]
    if case == "pickle":
        import pickle
        fmus["encoder"] = _b64(pickle.dumps({"arrays": {}, "attrs": _Payload(marker)}))
    elif case == "truncated":
        fmus["imu"] = fmus["imu"][:len(fmus["imu"]) // 2 // 4 * 4]
    elif case == "other fmu":
        fmus["encoder"] = fmus["imu"]
    elif case == "bad base64":
        fmus["encoder"] = "not base64!"
    elif case == "no values":
        del doc["values"]
    elif case == "no fmu":
        del fmus["plant"]
    elif case == "string time":
        doc["time"] = "0.02"
    elif case == "negative step":
        doc["step"] = -20
    elif case == "huge step":
        doc["step"] = 10 ** 18
    elif case == "float step":
        doc["step"] = 1e18
    elif case == "other step":
        doc["step"] = 5
    elif case == "bad structure":
        doc["structure"]["base_step"] = "fast"
    bad = tmp_path / "bad.json"
    bad.write_text("{not json" if case == "not json" else json.dumps(doc))
    code = main(["run", str(SCENARIO), "--set", "scenario.stop_time=0.05", "--no-progress",
                 "--out", str(tmp_path / "out"), "--from-state", str(bad)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and match in err and len(err.strip().splitlines()) == 1, err
    assert not marker.exists()
    if case == "pickle":
        assert "a pickle" in err and "data only" in err
    if case == "truncated":
        assert "truncated" in err
    if case == "other fmu":
        assert "another FMU or build" in err and "'Imu'" in err


def test_the_cli_state_file_resumes(cli_state, tmp_path: Path, capsys) -> None:
    """The file the bad ones above are made from is good: the run from it equals the whole one."""
    path, _ = cli_state
    assert main(["run", str(SCENARIO), "--set", "scenario.stop_time=0.05", "--no-progress",
                 "--out", str(tmp_path / "out"), "--from-state", str(path)]) == 0
    whole, forked = Result.load(path.parent / "run"), Result.load(tmp_path / "out")
    first = np.searchsorted(whole.time, 0.02 - 1e-9)
    assert_array_equal(forked.data, whole.data[first:])
