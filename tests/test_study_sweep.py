"""``flexfusion study sweep`` (orchestration/study_sweep.py): any scenario, any estimator meeting
the contract, seeds and grid / Latin hypercube sweeps. Tiny sizes: the replay scenario (a
recorded log, so every seed gives the same run) cut to 1 s."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study, study_sweep
from orchestration.cli import main
from orchestration.master import run
from orchestration.metrics import rmse
from orchestration.scenario import scenario_document
from toys import with_third_party

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

REPO = Path(__file__).resolve().parent.parent
AFTER = 0.5                                                   # s, as the replay scenario's metrics


@pytest.fixture(scope="module")
def scenarios(tmp_path_factory, third_party_fmus) -> dict[str, Path]:
    """The replay scenario (1 s) with a third-party-style estimator beside ours, ``toy``, which
    meets the contract, and the same with ``leaky``, which does not (tests/fmus/third_party)."""
    folder = tmp_path_factory.mktemp("sweep")
    doc = scenario_document(REPO / "orchestration" / "scenarios" / "replay_log.toml",
                            ["scenario.stop_time=1.0"])
    doc["record"]["variables"] += ["toy.p_tool_hat"]
    ok = with_third_party(doc, third_party_fmus, folder / "replay_third_party.toml", source="log.q_m_meas")
    leaky = with_third_party(ok, third_party_fmus, folder / "replay_leaky.toml", "leaky", "LeakyEstimator",
                             source="")
    return {"ok": ok, "leaky": leaky}


@pytest.fixture
def scenario(scenarios) -> Path:
    return scenarios["ok"]


def _sweep(scenario: Path, out: Path, *extra: str) -> int:
    return main(["study", "sweep", str(scenario), "--truth", "log.p_tool", "--after", str(AFTER),
                 "--workers", "1", "--no-progress", "--out", str(out), *extra])


def test_a_third_party_estimator_is_studied_beside_ours(scenario, tmp_path, capsys):
    """Its RMSE, and our EKF's RMSE, ANEES and ANIS, are those the scenario's own run gives
    (metrics.compute on the recorded run: an independent path), every seed alike (a log); the
    EKF's arm angles are judged against the log's truth q_a (the log has no dq_a: no rate error),
    the toy gives no arm estimate."""
    out = tmp_path / "study"
    assert _sweep(scenario, out, "--estimator", "toy", "--estimator", "ekf", "--runs", "2") == 0
    data = json.loads((out / "study.json").read_text())
    r = run(scenario, out_dir=tmp_path / "run")
    keep = r.time >= AFTER - 1e-12
    toy, ekf = (data["points"][0]["estimators"][n] for n in ("toy", "ekf"))
    assert_allclose(toy["position_rmse_per_seed"], [rmse(r["toy.p_tool_hat"][keep], r["log.p_tool"][keep])] * 2,
                    rtol=1e-12)
    assert_allclose(ekf["position_rmse_mean"], r.metrics["ekf_position_rmse"], rtol=1e-12)
    assert ekf["position_rmse_std"] == 0.0 and toy["nees"] is None and toy["nis"] is None
    assert_allclose(ekf["nees"]["mean"], r.metrics["ekf_angle_nees"], rtol=1e-12)
    assert_allclose(ekf["nis"]["mean"], r.metrics["ekf_nis"], rtol=1e-12)
    assert ekf["nis"]["dof"] == 4 and ekf["nees"]["dof"] == 2      # the scenario's nis metric; q_a
    lo, hi = ekf["nees"]["band_95"]
    assert 0 < lo < 2 < hi                                          # the band of the mean of 2 runs
    assert_allclose(ekf["arm"]["q_a_hat"]["rmse_per_seed"],
                    [rmse(r["ekf.q_a_hat"][keep], r["log.q_a"][keep])] * 2, rtol=1e-12)
    assert list(ekf["arm"]) == ["q_a_hat"] and ekf["arm"]["q_a_hat"]["truth"] == "log.q_a"
    assert data["estimators"]["toy"]["gives"] == {"nees": False, "nis": None, "nis_dof": None, "arm": []}
    assert toy["arm"] == {}
    rows = list(csv.DictReader((out / "study.csv").open()))
    assert [row["estimator"] for row in rows] == ["toy", "ekf"]
    assert rows[0]["q_a_hat_rmse_mean"] == "" and float(rows[1]["q_a_hat_rmse_mean"]) == ekf["arm"]["q_a_hat"]["rmse_mean"]
    assert (out / "study.png").stat().st_size > 0
    assert "toy" in capsys.readouterr().out


def test_a_grid_of_2x2_points_runs_their_product(scenario, tmp_path):
    """Each point's parameters reach its runs: the EKF's RMSE differs between points, the
    kinematic toy (no such parameter) is the same at all four."""
    out = tmp_path / "grid"
    assert _sweep(scenario, out, "--estimator", "ekf", "--estimator", "toy", "--no-plots",
                  "--grid", "ekf.r_acc=1e-4,4e-4", "--grid", "ekf.r_motor=1.2e-9,5e-9") == 0
    data = json.loads((out / "study.json").read_text())
    assert [p["parameters"] for p in data["points"]] == [
        {"ekf.r_acc": a, "ekf.r_motor": m} for a in (1e-4, 4e-4) for m in (1.2e-9, 5e-9)]
    ekf = [p["estimators"]["ekf"]["position_rmse_mean"] for p in data["points"]]
    toy = [p["estimators"]["toy"]["position_rmse_mean"] for p in data["points"]]
    assert len(set(ekf)) == 4 and len(set(toy)) == 1
    assert len(list(csv.DictReader((out / "study.csv").open()))) == 8


def test_a_latin_hypercube_is_stratified_and_reproducible_with_its_seed():
    lhs = ["ekf.r_acc=1e-4:4e-4", "ekf.q_jerk=1e-6:1e-5"]
    points = study_sweep.sweep_points(lhs=lhs, samples=3, lhs_seed=7)
    assert points == study_sweep.sweep_points(lhs=lhs, samples=3, lhs_seed=7)
    assert points != study_sweep.sweep_points(lhs=lhs, samples=3, lhs_seed=8)
    for key, lo, hi in (("ekf.r_acc", 1e-4, 4e-4), ("ekf.q_jerk", 1e-6, 1e-5)):
        strata = sorted(int((p[key] - lo) / (hi - lo) * 3) for p in points)
        assert strata == [0, 1, 2]                       # one sample in each third of each range
    with pytest.raises(study.StudyError, match="the seeds are --runs and --first-seed"):
        study_sweep.sweep_points(grid=["scenario.seed=1,2"])
    grid = study_sweep.sweep_points(grid=["ekf.r_motor=1e-9,2e-9"], lhs=lhs, samples=3, lhs_seed=7)
    assert len(grid) == 6 and [p["ekf.r_acc"] for p in grid[3:]] == [p["ekf.r_acc"] for p in points]


def test_a_latin_hypercube_study_runs_its_samples(scenario, tmp_path):
    out = tmp_path / "lhs"
    assert _sweep(scenario, out, "--estimator", "ekf", "--no-plots", "--lhs", "ekf.r_acc=1e-4:4e-4",
                  "--samples", "3", "--lhs-seed", "5") == 0
    data = json.loads((out / "study.json").read_text())
    assert [p["parameters"] for p in data["points"]] == study_sweep.sweep_points(
        lhs=["ekf.r_acc=1e-4:4e-4"], samples=3, lhs_seed=5)
    assert len({p["estimators"]["ekf"]["position_rmse_mean"] for p in data["points"]}) == 3


@pytest.mark.parametrize("name, message", [
    ("nosuch", r"^error: --estimator nosuch: scenario 'replay_log' has no component 'nosuch' \(components: .*toy.*\)$"),
    ("leaky", r"^error: --estimator leaky: LeakyEstimator.fmu does not meet the estimator contract "
              r".*required-outputs: p_tool_hat\[1\] \(missing\).*$"),
])
def test_a_bad_or_non_contract_estimator_is_one_line_and_exit_2(scenarios, tmp_path, capsys, name, message):
    assert _sweep(scenarios["leaky"], tmp_path / "bad", "--estimator", "ekf", "--estimator", name) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.match(message, err[0]), err
    assert not list((tmp_path / "bad" / "jobs").glob("*.pickle"))     # no run was started


def test_resume_reuses_the_finished_runs(scenario, tmp_path):
    out = tmp_path / "resumed"
    args = ("--estimator", "toy", "--no-plots", "--grid", "ekf.r_acc=1e-4,4e-4")
    assert _sweep(scenario, out, *args) == 0
    first = (out / "study.json").read_text()
    assert _sweep(scenario, out, *args) == 2                          # not over a finished study
    assert _sweep(scenario, out, *args, "--resume") == 0
    status = json.loads((out / "status.json").read_text())
    assert (status["status"], status["jobs_reused_now"], status["jobs_computed_now"]) == ("ok", 2, 0)
    assert (out / "study.json").read_text() == first
    assert np.isfinite(json.loads(first)["points"][1]["estimators"]["toy"]["max_error"])


def test_seeds_are_the_scenarios_seed_on_the_flagship(tmp_path):
    """On a simulated robot the seeds change the sensor noise: run i is ``scenario.seed =
    first_seed + i``, as a plain run with that seed gives, the arm angles, rates and
    accelerations against the plant's; ANIS without degrees of freedom (the flagship has no nis
    metric) has no band."""
    flagship = REPO / "orchestration" / "scenarios" / "flagship.toml"
    out = tmp_path / "flagship"
    assert main(["study", "sweep", str(flagship), "--estimator", "ekf", "--runs", "2", "--first-seed", "3",
                 "--set", "scenario.stop_time=0.3", "--after", "0.1", "--workers", "1", "--no-progress",
                 "--no-plots", "--out", str(out)]) == 0
    data = json.loads((out / "study.json").read_text())
    ekf = data["points"][0]["estimators"]["ekf"]
    doc = scenario_document(flagship)
    doc["record"]["variables"] += ["plant.dq_a", "plant.ddq_a", "ekf.ddq_a_hat"]
    r = study.simulate(doc, ["scenario.stop_time=0.3", "scenario.seed=4"])
    keep = r.time >= 0.1 - 1e-12
    # judged by the flagship's tracker by default (its fresh samples at their stamps), the
    # plant's truth beside it
    assert data["against"] == "reference" and data["judge"]["variable"] == "tracker.p_tool_meas"
    from orchestration.metrics import at_sample_times
    t, est, ref = at_sample_times(r.time, r["ekf.p_tool_hat"], r["tracker.p_tool_meas"], r["tracker.t_meas"])
    assert_allclose(ekf["position_rmse_per_seed"][1], rmse(est[t >= 0.1 - 1e-12], ref[t >= 0.1 - 1e-12]),
                    rtol=1e-12)
    assert ekf["truth"]["variable"] == "plant.p_tool"
    assert_allclose(ekf["truth"]["position_rmse_per_seed"][1],
                    rmse(r["ekf.p_tool_hat"][keep], r["plant.p_tool"][keep]), rtol=1e-12)
    assert ekf["position_rmse_std"] > 0
    assert list(ekf["arm"]) == ["q_a_hat", "dq_a_hat", "ddq_a_hat"]
    for est in ekf["arm"]:
        assert_allclose(ekf["arm"][est]["rmse_per_seed"][1],
                        rmse(r[f"ekf.{est}"][keep], r[f"plant.{est[:-4]}"][keep]), rtol=1e-12)
    assert ekf["nis"]["band_95"] is None and np.isfinite(ekf["nis"]["mean"])


REPLAY = REPO / "orchestration" / "scenarios" / "replay_log.toml"


def _replay_sweep(out: Path, **kw):
    out.mkdir()
    return study_sweep.run_study(REPLAY, ["ekf"], out, truth="log.p_tool", runs=2, after=AFTER,
                                 grid=["ekf.r_acc=1e-4,4e-4"], overrides=["scenario.stop_time=1.0"], workers=1,
                                 progress=False, plots=False, **kw)


def test_the_batched_engine_gives_the_fmus_numbers(tmp_path):
    """Every component ours: the runs go to the batched engine (one group on one worker), all
    four checked through the FMUs (identical to 1e-12), and the study's figures are those of
    --engine fmu."""
    batched = _replay_sweep(tmp_path / "b", check_runs=4)
    eng = batched["engine"]
    assert eng["used"] == "batched" and eng["groups"] == 1 and len(eng["checked_runs"]) == 4
    assert eng["max_relative_difference"] <= study.CHECK_RTOL
    fmu = _replay_sweep(tmp_path / "f", engine="fmu")
    assert fmu["engine"] == {"used": "fmu"}
    for pb, pf in zip(batched["points"], fmu["points"]):
        for key in ("position_rmse_per_seed", "max_error"):
            assert_allclose(pb["estimators"]["ekf"][key], pf["estimators"]["ekf"][key], rtol=study.CHECK_RTOL)
        assert_allclose(pb["estimators"]["ekf"]["nees"]["mean"], pf["estimators"]["ekf"]["nees"]["mean"],
                        rtol=study.CHECK_RTOL)


def test_a_difference_from_the_fmus_stops_the_sweep(tmp_path, monkeypatch):
    """A batched estimate off by 1e-9 relative stops the study, naming the run, the series and
    the difference (the jobs on threads here, so that the change reaches them)."""
    from concurrent.futures import ThreadPoolExecutor
    from contextlib import contextmanager

    @contextmanager
    def threads(workers=None, scheduler=None):
        with ThreadPoolExecutor(1) as ex:
            yield ex

    batched_job = study_sweep.batched_job

    def off(doc, runs, variables):
        out = batched_job(doc, runs, variables)
        out[-1]["ekf.p_tool_hat"] = out[-1]["ekf.p_tool_hat"] * (1 + 1e-9)
        return out

    monkeypatch.setattr(study, "open_executor", threads)
    monkeypatch.setattr(study_sweep, "batched_job", off)
    with pytest.raises(study.StudyError, match=r"run .*ekf.r_acc=0.0004 scenario.seed=2: ekf.p_tool_hat differs "
                                               r"by 1e-09 relative .*--engine fmu"):
        _replay_sweep(tmp_path / "off")


def test_a_logs_tracker_columns_are_the_default_judge(tmp_path):
    """A real robot's log has no truth but a laser tracker: mapped to the LogReplay's
    ``p_tool_meas`` and ``t_tool_meas``, it is the study's default judge (its fresh samples at
    their stamps; here 500 Hz, held over two rows, offset by (10, -20) um), with no truth column,
    no arm errors and no NEES; the per-seed RMSE recomputed from a plain run."""
    import csv as _csv
    from orchestration.metrics import at_sample_times
    rows = list(_csv.reader((REPLAY.parent / "replay_example_log.csv").open()))
    head, data = rows[0], np.array(rows[1:], dtype=float)
    t = data[:, head.index("time")]
    p = data[:, [head.index("plant.p_tool[1]"), head.index("plant.p_tool[2]")]]
    k = np.arange(len(t)) // 2 * 2
    meas, stamp = p[k] + [1e-5, -2e-5], t[k]
    log = tmp_path / "log.csv"
    with log.open("w", newline="") as fh:
        w = _csv.writer(fh)
        w.writerow(head + ["tracker.p_tool_meas[1]", "tracker.p_tool_meas[2]", "tracker.t_meas"])
        for row, m, s in zip(rows[1:], meas, stamp):
            w.writerow(row + [repr(float(m[0])), repr(float(m[1])), repr(float(s))])
    columns = ("q_m_meas = encoder.q_m_meas; t_meas = encoder.t_meas; acc_s = imu.acc_s; "
               "dddq_a_ref = controller.dddq_a_ref; p_tool_meas = tracker.p_tool_meas; t_tool_meas = tracker.t_meas")
    sets = [f'log.log_file="{log}"', f'log.columns="{columns}"', "scenario.stop_time=1.0"]
    doc = scenario_document(REPLAY)
    doc["metrics"] = []                             # the scenario's metrics read the truth columns
    doc["record"]["variables"] = ["ekf.p_tool_hat", "log.p_tool_meas", "log.t_tool_meas"]
    scen = doc
    (tmp_path / "out").mkdir()
    data = study_sweep.run_study(scen, ["ekf"], tmp_path / "out", overrides=sets, after=AFTER, workers=1,
                                 progress=False, plots=False, engine="fmu")
    assert data["against"] == "reference" and data["truth"] is None
    assert data["judge"] == {"against": "reference", "component": "log", "fmu": "LogReplay",
                             "variable": "log.p_tool_meas", "stamp": "log.t_tool_meas"}
    ekf = data["points"][0]["estimators"]["ekf"]
    assert ekf["truth"] is None and ekf["arm"] == {} and ekf["nees"] is None
    r = study.simulate(scen, sets)
    ts, est, ref = at_sample_times(r.time, r["ekf.p_tool_hat"], r["log.p_tool_meas"], r["log.t_tool_meas"])
    assert len(ts) == len(np.unique(r["log.t_tool_meas"])) < len(r.time)      # 500 Hz of 1 kHz rows
    keep = ts >= AFTER - 1e-12
    assert_allclose(ekf["position_rmse_per_seed"][0], rmse(est[keep], ref[keep]), rtol=1e-12)
