"""Tests of orchestration.study_montecarlo (the 2012 paper's Monte Carlo study, Fig. 3, Table 1).

The FMUs are the test run's own build (tests/conftest.py), never a possibly stale dist/fmus.
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import cli, study, study_montecarlo
from orchestration.scenario import scenario_document
from references import STUDY_RTOL, assert_same_document
from toys import with_third_party

SCENARIO = Path(study_montecarlo.__file__).resolve().parent / "scenarios" / "axelsson2012.toml"
SHORT = ["scenario.stop_time=0.5"]

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # also for the module-scoped runs


def small_study(out: Path) -> dict:
    """The small study of these tests (3 runs of 0.5 s, one sweep point, 3 validation runs)."""
    return study_montecarlo.run_study(SCENARIO, 3, out, SHORT, workers=1, progress=False, after=0.2,
                                      sweep=(1.0,), sweep_runs=2, validation_runs=3)


def comparable(study_json: Path) -> dict:
    """study.json without what changes from run to run (wall times, executor, the file's path)."""
    saved = json.loads(study_json.read_text())
    for key in ("wall_time_s", "executor", "scenario_file"):
        saved.pop(key)
    saved["engine"].pop("engine_wall_time_s")
    return saved


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc1")
    return out, small_study(out)


#: Table 1 of Axelsson, Karlsson, Norrlöf (2012), transcribed here independently of the study's copy.
TABLE1_TEXT = {"accelerometer": {"position": 1.25e-5, "velocity": 7.57e-5, "acceleration": 1.23e-3},
               "no_accelerometer": {"position": 2.18e-5, "velocity": 4.08e-4, "acceleration": 3.91e-3}}


def test_paper_values_are_the_papers_text():
    """The numbers the study compares with are the paper's: Table 1 and its caption (500 runs),
    eq. 26, Fig. 4's caption (20 runs). TABLE1_TEXT and the eq. 26 values here were checked by
    hand against the paper's text (Table 1, eq. 26, the captions of Figs. 3 and 4) on
    2026-11-30."""
    assert study_montecarlo.PAPER_TABLE1 == TABLE1_TEXT
    assert study_montecarlo.PAPER_TABLE1_RUNS == 500 and study_montecarlo.PAPER_FIG4_RUNS == 20
    assert (study_montecarlo.PAPER_Q_JERK, study_montecarlo.PAPER_R_MOTOR, study_montecarlo.PAPER_R_ACC) \
        == (4e-6, 1e-6, 1e-4)


def test_scenario_reads_eq26_motor_side():
    """Eq. 26's R with the motor angle motor side (eqs. 15-16): the encoder's standard deviation
    is sqrt(1e-6) rad, the EKFs' r_motor 1e-6 rad^2, the accelerometer 0.01 m/s^2 and 1e-4."""
    from orchestration.scenario import load_scenario
    for name in ("axelsson2012.toml", "axelsson2012_pf.toml"):
        sc = load_scenario(SCENARIO.with_name(name))
        assert_allclose(sc.components["encoder"].parameters["noise"] ** 2, study_montecarlo.PAPER_R_MOTOR)
        assert_allclose(sc.components["imu"].parameters["acc_noise"] ** 2, study_montecarlo.PAPER_R_ACC)
        filters = [c for c in sc.components.values() if c.model_identifier in study_montecarlo.FILTER_FMUS]
        assert filters
        for c in filters:
            assert c.parameters["r_motor"] == study_montecarlo.PAPER_R_MOTOR
            assert c.parameters["r_acc"] == study_montecarlo.PAPER_R_ACC


def test_pf_scenario_is_algorithm_1_with_labelled_variants():
    from orchestration.scenario import load_scenario
    sc = load_scenario(SCENARIO.with_name("axelsson2012_pf.toml"))
    pf = {n: c.parameters for n, c in sc.components.items() if c.model_identifier == "ParticleFilter"}
    assert (pf["pf_alg1"]["proposal"], pf["pf_alg1"]["resampling"], pf["pf_alg1"]["bandwidth"]) \
        == ("prior", "always", 0.0)
    assert pf["pf_regularised"]["bandwidth"] > 0 and pf["pf_regularised"]["proposal"] == "prior"
    assert pf["pf_ekf_proposal"]["proposal"] == "ekf" and pf["pf_ekf_proposal"]["bandwidth"] == 0.0


def test_study_json_schema(small):
    """The sweep (with the paper's Q as its own row), the consistency figures, the CRLB
    validation, Table 1 with ratios, the findings and the wall time are in study.json."""
    out, _ = small
    saved = json.loads((out / "study.json").read_text())
    sw = saved["q_jerk_sweep"]
    assert [r["q_jerk"] for r in sw["rows"]] == [4e-6, 1.0]
    assert sw["rows"][0]["label"].startswith("paper") and sw["rows"][1]["label"] == ""
    assert sw["selected_q_jerk"] in (4e-6, 1.0) and sw["runs_per_value"] == 2
    for row in sw["rows"]:
        assert set(row["filters"]) == {"ekf_acc", "ekf_motor"}
        for e in row["filters"].values():
            assert e["anees"] > 0 and 0 <= e["anees_fraction_in_band"] <= 1
            lo, hi = e["anees_band_95"]
            assert lo < 6 < hi
    for name in ("ekf_acc", "ekf_motor"):
        assert saved["summary"][name]["anees"] > 0
    v = saved["crlb_validation"]
    assert v["runs"] == 3 and v["q_true"] == 1.0
    for k in ("matched_acc", "matched_motor", "overtuned_acc", "overtuned_motor"):
        assert set(v[k]) >= {"rmse", "crlb_true_q", "crlb_filter_q"}
    t1 = saved["table1"]
    assert t1["paper"] == TABLE1_TEXT and t1["paper_runs"] == 500 and t1["runs"] == 3
    for key in ("accelerometer_over_paper", "no_accelerometer_over_paper", "ratio_without_over_with"):
        assert set(t1[key]) == set(study_montecarlo.GROUPS)
    assert_allclose(t1["accelerometer_over_paper"]["position"],
                    t1["accelerometer"]["position"] / 1.25e-5, rtol=1e-12)
    assert saved["findings"]
    for f in saved["findings"]:
        assert set(f) == {"claim", "ours", "reproduced", "why"} and f["reproduced"] in ("yes", "no")
    w = saved["wall_time_s"]
    assert w["jobs"] == 3 + 2 * 2 and w["total"] >= w["runs_and_sweep"] > 0
    assert saved["executor"] == {"workers": 1, "scheduler": None}
    assert "not a lower bound" in saved["crlb_note"]


def test_nees_of_a_known_case():
    """NEES = e^T P^-1 e with P unpacked from the EKF's P_x (lower triangle row by row)."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 6, 6))
    P = A @ np.swapaxes(A, 1, 2) + 6 * np.eye(6)
    e = rng.standard_normal((4, 6))
    packed = P[:, np.tril_indices(6)[0], np.tril_indices(6)[1]]
    assert packed.shape == (4, 21)
    assert_allclose(study_montecarlo.nees(e, packed), [ei @ np.linalg.solve(Pi, ei) for ei, Pi in zip(e, P)],
                    rtol=1e-12)


def test_sweep_row_of_the_scenario_value_repeats_the_main_runs(small):
    """The sweep's q_jerk = 1 row (seeds 1-2) and the main runs (q_jerk = 1 in the scenario,
    seeds 1-3) share seeds 1-2: the filters see the same data, so recomputing the main runs'
    summary from those two seeds gives the sweep row's numbers."""
    _, data = small
    sc, filters, plant = study_montecarlo._scenario_parts(str(SCENARIO), SHORT)
    runs = [study_montecarlo.run_one(str(SCENARIO), SHORT + [f"scenario.seed={s}"], filters, plant,
                                     filters[0].ratio) for s in (1, 2)]
    keep = runs[0]["time"] >= 0.2
    summary, _ = study_montecarlo._summarise(runs, filters, keep)
    row = data["q_jerk_sweep"]["rows"][1]["filters"]
    for name in ("ekf_acc", "ekf_motor"):
        assert_allclose(row[name]["rmse_position"], summary[name]["rmse_position"], rtol=1e-12)
        assert_allclose(row[name]["anees"], summary[name]["anees"], rtol=1e-12)


def test_small_study_writes_json_and_figure(small):
    out, data = small
    saved = json.loads((out / "study.json").read_text())
    assert (out / "fig3.png").stat().st_size > 0
    assert not (out / "fig4.png").exists()                  # no particle filter in the scenario
    assert saved["runs"] == 3 and saved["seeds"] == [1, 3]
    assert set(saved["summary"]) == {"ekf_acc", "ekf_motor"}
    t = np.array(saved["per_time"]["time"])
    assert_allclose(np.diff(t), 0.01, rtol=1e-9)             # the filters' 100 Hz instants
    assert_allclose(t[0], 0.001)                             # t_j + base step
    for name in ("ekf_acc", "ekf_motor"):
        s = saved["summary"][name]
        for g in study_montecarlo.GROUPS:
            assert np.isfinite(s[f"rmse_{g}"]) and s[f"rmse_{g}"] > 0
            assert s[f"crlb_{g}"] > 0
            assert len(saved["per_time"][name][g]) == len(t) == len(saved["crlb"][name][g])
    # only the sensor noise changes from run to run
    assert saved["truth_max_deviation_between_runs"] == 0.0
    assert saved["table1"]["paper"]["accelerometer"]["position"] == 1.25e-5


def test_rmse_is_eq27_of_the_runs(small, tmp_path):
    """The per-time RMSE is eq. 27 of the runs' errors (recomputed from the jobs directly)."""
    _, data = small
    sc, filters, plant = study_montecarlo._scenario_parts(str(SCENARIO), SHORT)
    runs = [study_montecarlo.run_one(str(SCENARIO), SHORT + [f"scenario.seed={s}"], filters, plant,
                                     filters[0].ratio) for s in (1, 2, 3)]
    e = np.stack([r["ekf_acc"][:, 0:2] for r in runs])
    assert_allclose(data["per_time"]["ekf_acc"]["position"], np.sqrt(np.mean(np.sum(e * e, 2), 0)),
                    rtol=1e-12)


def test_same_numbers_with_two_workers_and_through_the_cli(small, tmp_path, capsys):
    _, one = small
    code = cli.main(["study", "montecarlo", str(SCENARIO), "--runs", "3", "--out", str(tmp_path),
                     "--workers", "2", "--no-progress", "--after", "0.2", "--no-plots",
                     "--sweep-runs", "0", "--validation-runs", "0", "--set", SHORT[0]])
    assert code == 0
    assert "ekf_acc" in capsys.readouterr().out
    two = json.loads((tmp_path / "study.json").read_text())
    assert two["summary"] == json.loads(json.dumps(one["summary"]))
    assert two["per_time"] == json.loads(json.dumps(study_montecarlo._jsonable(one["per_time"])))


def test_cli_reports_a_bad_scenario_in_one_line(tmp_path, capsys):
    code = cli.main(["study", "montecarlo", str(tmp_path / "missing.toml"), "--runs", "2",
                     "--out", str(tmp_path), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.toml" in err[0]


def test_resume_recomputes_only_the_missing_runs_with_the_same_numbers(tmp_path, capsys):
    """On the FMU engine each run is a stored job (the batched engine computes all runs at once,
    in seconds, and stores none)."""
    argv = ["study", "montecarlo", str(SCENARIO), "--engine", "fmu", "--runs", "3", "--out", str(tmp_path), "--workers", "2",
            "--no-progress", "--after", "0.2", "--no-plots", "--no-crlb", "--sweep-runs", "0",
            "--validation-runs", "0", "--set", SHORT[0]]
    assert cli.main(argv) == 0
    first = (tmp_path / "study.json").read_text()
    jobs = sorted((tmp_path / "jobs").glob("*.pickle"))
    assert len(jobs) == 3
    jobs[1].unlink()                                  # as if the study had stopped before it
    assert cli.main(argv) == 2                        # the folder holds a study: not mixed in silently
    assert "add --resume" in capsys.readouterr().err
    assert cli.main(argv + ["--resume"]) == 0
    status = json.loads((tmp_path / "status.json").read_text())
    assert (status["status"], status["jobs_computed_now"], status["jobs_reused_now"]) == ("ok", 1, 2)
    assert status["command"] == " ".join(["flexfusion", *argv, "--resume"])
    again = json.loads((tmp_path / "study.json").read_text())
    first = json.loads(first)
    assert again["summary"] == first["summary"] and again["per_time"] == first["per_time"]


def test_an_unusable_out_folder_fails_before_any_run(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    t0 = time.perf_counter()
    code = cli.main(["study", "montecarlo", str(SCENARIO), "--runs", "500", "--out", str(tmp_path / "file" / "mc"),
                     "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err == f"error: --out {tmp_path / 'file' / 'mc'}: Not a directory\n"
    assert time.perf_counter() - t0 < 60              # hang guard: 500 runs would take minutes


def test_a_scenario_lacking_needed_variables_fails_before_any_run(tmp_path, capsys):
    text = SCENARIO.read_text().replace('"ekf_acc.ddq_a_hat", ', "").replace('"plant.dq_m",', "")
    path = tmp_path / "lacking.toml"
    path.write_text(text)
    (tmp_path / "identified_robot_ideal.toml").write_text(
        SCENARIO.with_name("identified_robot_ideal.toml").read_text())
    code = cli.main(["study", "montecarlo", str(path), "--runs", "50", "--out", str(tmp_path / "out"),
                     "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0] == ("error: scenario 'axelsson2012' does not record what the Monte Carlo study needs: "
                      "ekf_acc.ddq_a_hat, plant.dq_m (add them to [record] variables)")
    assert list((tmp_path / "out" / "jobs").iterdir()) == []


def test_same_numbers_on_a_dask_local_cluster(small, tmp_path):
    pytest.importorskip("distributed")
    _, one = small
    dask = study_montecarlo.run_study(SCENARIO, 3, tmp_path, SHORT, workers=2, scheduler="local",
                                      progress=False, after=0.2, plots=False, sweep_runs=0,
                                      validation_runs=0)
    assert dask["summary"] == one["summary"]
    for name in one["summary"]:
        for g in study_montecarlo.GROUPS:
            assert np.array_equal(dask["per_time"][name][g], one["per_time"][name][g])


def test_bad_arguments_are_study_errors(tmp_path):
    with pytest.raises(study.StudyError, match="--runs"):
        study_montecarlo.run_study(SCENARIO, 0, tmp_path)
    with pytest.raises(study.StudyError, match="--after"):
        study_montecarlo.run_study(SCENARIO, 1, tmp_path, SHORT, after=5.0)
    with pytest.raises(study.StudyError, match="no_such"):
        study_montecarlo.run_study(SCENARIO, 1, tmp_path, ["no_such.x=1"])
    with pytest.raises(study.StudyError, match="sweep"):
        study_montecarlo.run_study(SCENARIO, 1, tmp_path, SHORT, sweep=(0.0,))
    with pytest.raises(study.StudyError, match="sweep-runs"):
        study_montecarlo.run_study(SCENARIO, 1, tmp_path, SHORT, sweep_runs=-1)


@pytest.fixture(scope="module")
def section4(tmp_path_factory):
    """Reduced size of the docs/figures.md figure (100 runs, full sweep): 30 runs, a 3-value sweep of 6 runs
    each, 30 validation runs (about 3 min on 2 workers)."""
    return study_montecarlo.run_study(SCENARIO, 30, tmp_path_factory.mktemp("mc30"), workers=2,
                                      progress=False, plots=False, sweep=(0.1, 1.0, 10.0), sweep_runs=6,
                                      validation_runs=30)


@pytest.mark.slow
def test_section4_accelerometer_lowers_every_rmse(section4):
    """Table 1's direction, which we reproduce: the accelerometer lowers the angle, velocity and
    acceleration RMSE (measured with 100 runs: 1.1x, 1.5x, 1.5x; the paper 1.74x, 5.4x, 3.2x, so
    the magnitudes are NOT reproduced, see the findings)."""
    r = section4["table1"]["ratio_without_over_with"]
    assert r["position"] > 1.03
    assert r["velocity"] > 1.3 and r["acceleration"] > 1.3


@pytest.mark.slow
def test_section4_q_jerk_is_the_consistent_choice(section4):
    """The scenario's q_jerk is the sweep's consistency choice, both EKFs' ANEES is within a
    factor 1.5 of 6 there, and the paper's literal Q (eq. 26) is grossly overconfident here."""
    sw = section4["q_jerk_sweep"]
    assert sw["selected_q_jerk"] == 1.0 == sw["scenario_q_jerk"]["ekf_acc"] == sw["scenario_q_jerk"]["ekf_motor"]
    for name in ("ekf_acc", "ekf_motor"):
        assert 4.0 <= section4["summary"][name]["anees"] <= 9.0
    paper = next(r for r in sw["rows"] if r["q_jerk"] == study_montecarlo.PAPER_Q_JERK)
    assert all(e["anees"] > 100 for e in paper["filters"].values())


@pytest.mark.slow
def test_section4_bound_validation_and_the_papers_construction(section4):
    """With the process noise the bound assumes, the matched EKF sits on the bound (within the
    Monte Carlo spread of 30 runs); on the section-4 plant (no process noise) the paper's
    construction with the filter's Q is beaten by the motor-only EKF: it is no bound there."""
    v = section4["crlb_validation"]
    for k in ("matched_acc", "matched_motor"):
        assert_allclose(v[k]["rmse"]["position"], v[k]["crlb_true_q"]["position"], rtol=0.06)
    for k in ("overtuned_acc", "overtuned_motor"):
        assert v[k]["rmse"]["position"] >= 0.95 * v[k]["crlb_true_q"]["position"]
    assert section4["summary"]["ekf_motor"]["rmse_over_crlb_position"] < 1.0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="not reproduced: the paper's 'RMSE close to the CRLB' with and without "
                   "accelerometer; 100 runs give 1.45x (with) and 0.58x (without): the paper-construction bound "
                   "takes the filter's Q while the plant has no process noise, and the motor velocity as a "
                   "noise-free input")
def test_section4_ekf_within_1_5x_of_the_crlb_with_and_without_accelerometer(section4):
    """The paper's Fig. 3 claim on its bound (eqs. 21-25), with and without accelerometer."""
    for name in ("ekf_acc", "ekf_motor"):
        assert 1.0 <= section4["summary"][name]["rmse_over_crlb_position"] <= 1.5


PF_SCENARIO = SCENARIO.with_name("axelsson2012_pf.toml")
PF_NAMES = ("pf_alg1", "pf_regularised", "pf_ekf_proposal")


def test_particle_filter_scenario_gives_fig4(tmp_path):
    d = study_montecarlo.run_study(PF_SCENARIO, 2, tmp_path, ["scenario.stop_time=0.2"]
                                   + [f"{n}.n_particles=100" for n in PF_NAMES],
                                   workers=1, progress=False, after=0.05, sweep_runs=0, validation_runs=0)
    assert (tmp_path / "fig4.png").stat().st_size > 0
    assert set(d["pf_vs_ekf"]) == set(PF_NAMES)
    for name in PF_NAMES:
        v = d["pf_vs_ekf"][name]
        assert v["ekf"] == "ekf_acc" and v["n_particles"] == 100
        assert_allclose(v["position_ratio"], d["summary"][name]["rmse_position"]
                        / d["summary"]["ekf_acc"]["rmse_position"])
    fig4 = [f for f in d["findings"] if f["claim"].startswith("Fig. 4")]
    assert len(fig4) == 2 and all(f["ours"].startswith("pf_alg1:") for f in fig4)   # Algorithm 1 only


@pytest.mark.slow
def test_pf_algorithm_1_needs_many_particles(tmp_path):
    """Reduced Fig. 4 (4 runs, 1.5 s): the paper's Algorithm 1 with 10000 particles is within
    1.25x of the EKF; with 1000 the plain bootstrap degenerates (more than 10x the EKF), while
    the regularised variant with 1000 stays within 1.25x."""
    short = ["scenario.stop_time=1.5", "pf_ekf_proposal.n_particles=1000"]
    d = study_montecarlo.run_study(PF_SCENARIO, 4, tmp_path / "a", short, workers=2, progress=False,
                                   plots=False, sweep_runs=0, validation_runs=0, crlb=False)
    assert d["pf_vs_ekf"]["pf_alg1"]["position_ratio"] <= 1.25
    few = study_montecarlo.run_study(PF_SCENARIO, 4, tmp_path / "b", short + [
        "pf_alg1.n_particles=1000", "pf_regularised.n_particles=1000"], workers=2, progress=False,
        plots=False, sweep_runs=0, validation_runs=0, crlb=False)
    assert few["pf_vs_ekf"]["pf_alg1"]["position_ratio"] > 10
    assert few["pf_vs_ekf"]["pf_regularised"]["position_ratio"] <= 1.25


# ---------------------------------------------------------------------------------------------
# without --estimator: main's study; with it: any estimator, ours or anyone's
# ---------------------------------------------------------------------------------------------
REFERENCE = Path(__file__).parent / "data" / "montecarlo_main_reference.json"


def save() -> None:
    """Re-record :data:`REFERENCE` from the working tree (``python tests/references.py montecarlo``)."""
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        small_study(Path(tmp))
        study_json = comparable(Path(tmp) / "study.json")
    REFERENCE.write_text(json.dumps({"how": "small_study() of tests/test_study_montecarlo.py, written by its save() "
                                            "(python tests/references.py montecarlo): study.json without wall times, "
                                            "executor and the file's path", "study": study_json}, indent=1) + "\n")


def test_without_estimator_the_study_is_its_reference(small):
    """No --estimator: study.json of the paper's study is its stored reference
    (tests/data/montecarlo_main_reference.json, first recorded from main before the generic
    studies; tests/references.py): every key, every number (tests/toys.assert_same_document)."""
    out, _ = small
    assert_same_document(comparable(out / "study.json"), json.loads(REFERENCE.read_text())["study"], STUDY_RTOL)


@pytest.fixture(scope="module")
def toy_scenarios(tmp_path_factory, third_party_fmus) -> dict[str, Path]:
    """The section-4 scenario (0.5 s) with the third-party estimator ``toy`` (its own step: the
    base step) fed by the encoder, and the same with ``leaky``, which misses the contract."""
    folder = tmp_path_factory.mktemp("mc_toy")
    ok = with_third_party(SCENARIO, third_party_fmus, folder / "axelsson2012_toy.toml", overrides=SHORT)
    leaky = with_third_party(ok, third_party_fmus, folder / "axelsson2012_leaky.toml", "leaky",
                             "LeakyEstimator", source="")
    return {"ok": ok, "leaky": leaky}


def _montecarlo(scenario: Path, out: Path, *extra: str) -> int:
    return cli.main(["study", "montecarlo", str(scenario), "--runs", "2", "--after", "0.2", "--sweep-runs", "0",
                     "--validation-runs", "0", "--workers", "1", "--no-progress", "--out", str(out), *extra])


def test_a_third_party_estimator_runs_beside_ours(toy_scenarios, tmp_path, capsys):
    """The issue's "must show": a contract-passing estimator that is not ours in the Monte Carlo
    beside our EKF. The batched engine cannot run it: one line says so and every run goes
    through the FMUs. Its tool-position RMSE (eq. 27 per time, averaged over t >= after) is that
    of plain runs of the same seeds, computed here; our EKF keeps its bound and Table 1 row."""
    out = tmp_path / "mc"
    assert _montecarlo(toy_scenarios["ok"], out, "--estimator", "ekf_acc", "--estimator", "toy") == 0
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        "montecarlo: the batched engine cannot run this study (it knows only the math of our FMUs, and "
        "'toy' (ThirdPartyEstimator) is not one of them): every run goes through the FMUs"]
    assert "toy" in captured.out
    data = json.loads((out / "study.json").read_text())
    assert data["engine"]["used"] == "fmu" and "'toy'" in data["engine"]["fallback"]
    assert data["estimators"] == ["ekf_acc", "toy"] and data["tool_truth"] == "plant.p_tool"
    toy, ekf = data["summary"]["toy"], data["summary"]["ekf_acc"]
    assert [k for k in toy if k.startswith("rmse")] == ["rmse_tool_position"]     # no arm estimate
    assert "crlb_position" in ekf and "anees" in ekf and "crlb_position" not in toy
    assert "accelerometer" in data["table1"] and "no_accelerometer" not in data["table1"]

    doc = scenario_document(toy_scenarios["ok"])
    doc["record"]["variables"] += ["plant.p_tool", "toy.p_tool_hat", "ekf_acc.p_tool_hat"]
    runs = [study.simulate(doc, [f"scenario.seed={s}"]) for s in (1, 2)]
    rows = slice(1, None, 10)                       # t_j + h of the EKF's 100 Hz steps
    keep = runs[0].time[rows] >= 0.2
    for name in ("toy", "ekf_acc"):
        e = np.stack([r[f"{name}.p_tool_hat"][rows] - r["plant.p_tool"][rows] for r in runs])
        per_time = np.sqrt(np.mean(np.sum(e * e, axis=2), axis=0))
        assert_allclose(data["per_time"][name]["tool_position"], per_time, rtol=1e-12)
        assert_allclose(data["summary"][name]["rmse_tool_position"], np.mean(per_time[keep]), rtol=1e-12)
    assert (out / "fig3.png").stat().st_size > 0 and (out / "tool_position.png").stat().st_size > 0


def test_our_estimators_named_stay_on_the_batched_engine(small, tmp_path):
    """``--estimator`` with ours only: the batched engine runs them (its check seeds agree with
    the FMUs, tool position included), and their angle RMSE is the paper study's."""
    out = tmp_path / "ours"
    assert cli.main(["study", "montecarlo", str(SCENARIO), "--runs", "3", "--after", "0.2", "--sweep-runs", "0",
                     "--validation-runs", "0", "--no-crlb", "--no-plots", "--check-seeds", "2", "--workers", "1",
                     "--no-progress", "--set", SHORT[0], "--estimator", "ekf_motor", "--estimator", "ekf_acc",
                     "--out", str(out)]) == 0
    data = json.loads((out / "study.json").read_text())
    assert data["engine"]["used"] == "batched" and data["engine"]["checked_seeds"] == [1, 3]
    assert data["engine"]["max_relative_difference"] <= study_montecarlo.CHECK_RTOL
    _, paper = small
    for name in ("ekf_acc", "ekf_motor"):
        s = data["summary"][name]
        for key in ("rmse_position", "rmse_velocity", "rmse_acceleration", "anees"):
            assert s[key] == paper["summary"][name][key], (name, key)
        assert 0 < s["rmse_tool_position"] < 1e-2


@pytest.mark.parametrize("name, message", [
    ("nosuch", r"^error: --estimator nosuch: scenario 'axelsson2012' has no component 'nosuch' \(components: .*toy.*\)$"),
    ("leaky", r"^error: --estimator leaky: LeakyEstimator.fmu does not meet the estimator contract "
              r".*required-outputs: p_tool_hat\[1\] \(missing\).*$"),
])
def test_a_bad_or_non_contract_estimator_is_one_line_and_exit_2(toy_scenarios, tmp_path, capsys, name, message):
    assert _montecarlo(toy_scenarios["leaky"], tmp_path / "bad", "--estimator", "toy", "--estimator", name) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.match(message, err[0]), err
    assert not list((tmp_path / "bad" / "jobs").glob("*.pickle"))     # no run was started


def test_an_estimator_of_some_arm_estimates_is_judged_on_those():
    """An estimator giving only the arm angles (and the tool position): its errors are those
    columns of the truth, its summary the angle and tool RMSE (eq. 27), no velocity, no NEES."""
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 1.0, 11)
    plant = {f"plant.{v}": rng.standard_normal((11, 2)) for v in ("q_a", "dq_a", "ddq_a", "q_m", "dq_m", "p_tool")}
    f = study_montecarlo.FilterInfo("mine", "Mine", False, 1, 0.1, {}, groups=("position",), tool=True, ours=False)
    runs = []
    for _ in range(3):
        est = {"mine.q_a_hat": rng.standard_normal((11, 2)), "mine.p_tool_hat": rng.standard_normal((11, 2))}
        values = {**plant, **est}
        runs.append(study_montecarlo._errors(t, np.arange(11), values.__getitem__, values.__getitem__, [f], "plant"))
        assert_allclose(runs[-1]["mine"], est["mine.q_a_hat"] - plant["plant.q_a"], rtol=0, atol=0)
        assert_allclose(runs[-1]["mine.tool"], est["mine.p_tool_hat"] - plant["plant.p_tool"], rtol=0, atol=0)
    summary, per_time = study_montecarlo._summarise(runs, [f], t >= 0.5)
    e = np.stack([r["mine"] for r in runs])
    assert_allclose(per_time["mine"]["position"], np.sqrt(np.mean(np.sum(e * e, 2), 0)), rtol=1e-12)
    assert sorted(summary["mine"]) == ["fmu", "rmse_position", "rmse_tool_position", "use_accelerometer"]
    assert study_montecarlo.needed([f], "plant") == [
        "plant.q_a", "plant.dq_a", "plant.ddq_a", "plant.q_m", "plant.dq_m", "plant.p_tool",
        "mine.q_a_hat", "mine.p_tool_hat"]


REALISTIC = SCENARIO.with_name("axelsson2012_realistic.toml")
#: 0.3 s: the realistic runs recomputed through the FMUs below are the batched engine's check
REALISTIC_SHORT = ["scenario.stop_time=0.3"]


def test_verdict_against_the_band():
    """Inside the 95 % band consistent (its edges included), above it over-confident (errors
    larger than the covariance says), below it under-confident."""
    band = (4.05, 8.33)
    assert study_montecarlo.verdict(6.0, band) == "consistent"
    assert study_montecarlo.verdict(4.05, band) == study_montecarlo.verdict(8.33, band) == "consistent"
    assert study_montecarlo.verdict(8.4, band) == "over-confident"
    assert study_montecarlo.verdict(4.0, band) == "under-confident"


def test_realistic_scenario_is_section_4_with_bias_states_and_a_tracker():
    """The realistic variant differs from the ideal one where it says: the plant's realism on,
    the model identified on that plant, the bias states on, a tracker; eq. 26's noise kept."""
    from orchestration.judge import reference_components
    from orchestration.scenario import load_scenario, scenario_document
    sc = load_scenario(REALISTIC)
    assert sc.components["plant"].parameters.get("ideal", False) is False
    import tomllib
    assert tomllib.loads(REALISTIC.read_text())["scenario"]["include"] == ["identified_robot.toml"]
    assert reference_components(scenario_document(REALISTIC)) == ["tracker"]
    assert_allclose(sc.components["encoder"].parameters["noise"] ** 2, study_montecarlo.PAPER_R_MOTOR)
    assert_allclose(sc.components["imu"].parameters["acc_noise"] ** 2, study_montecarlo.PAPER_R_ACC)
    for name in ("ekf_acc", "ekf_motor"):
        p = sc.components[name].parameters
        assert p["use_bias"] is True
        assert (p["r_motor"], p["r_acc"]) == (study_montecarlo.PAPER_R_MOTOR, study_montecarlo.PAPER_R_ACC)


@pytest.fixture(scope="module")
def realistic(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc_realistic")
    return out, study_montecarlo.run_study(REALISTIC, 2, out, REALISTIC_SHORT, workers=1, progress=False,
                                           after=0.1, crlb=False, sweep_runs=0, validation_runs=0, check_seeds=0)


def test_realistic_study_judges_the_tool_by_the_tracker_with_the_truth_beside(realistic):
    """On the realistic scenario each filter's tool position is scored against the tracker
    first (its samples at its stamps), the truth in its own named column; both recomputed here
    from the runs through the FMUs; ANEES with its band and a verdict per filter."""
    out, data = realistic
    assert data["tool_judge"]["against"] == "reference"
    assert data["tool_judge"]["variable"] == "tracker.p_tool_meas"
    assert data["tool_judge"]["stamp"] == "tracker.t_meas"
    assert data["tool_truth"] == "plant.p_tool"
    sc, filters, plant = study_montecarlo._scenario_parts(str(REALISTIC), REALISTIC_SHORT)
    runs = [study_montecarlo.run_one(str(REALISTIC), REALISTIC_SHORT + [f"scenario.seed={s}"], filters, plant,
                                     filters[0].ratio, "tracker") for s in (1, 2)]
    keep = runs[0]["time"] >= 0.1
    for name in ("ekf_acc", "ekf_motor"):
        s = data["summary"][name]
        ref = np.stack([r[name + ".tool_reference"] for r in runs])
        truth = np.stack([r[name + ".tool"] for r in runs])
        assert_allclose(s["rmse_tool_position"], np.mean(np.sqrt(np.mean(np.sum(ref ** 2, 2), 0))[keep]),
                        rtol=1e-12)
        assert_allclose(s["rmse_tool_position_truth"], np.mean(np.sqrt(np.mean(np.sum(truth ** 2, 2), 0))[keep]),
                        rtol=1e-12)
        # the tracker's noise (0.02 mm per axis) and its 1 ms skew are in the first column only
        assert s["rmse_tool_position"] != s["rmse_tool_position_truth"]
        lo, hi = s["anees_band_95"]
        assert s["verdict"] == study_montecarlo.verdict(s["anees"], (lo, hi))
    saved = json.loads((out / "study.json").read_text())
    assert saved["summary"]["ekf_acc"]["verdict"] in ("consistent", "over-confident", "under-confident")
    assert "tool_position_truth" in saved["per_time"]["ekf_acc"]
    assert (out / "tool_position.png").stat().st_size > 0


def test_the_tracker_error_is_the_estimate_minus_the_tracker_at_its_stamps(realistic):
    """The reference column is p_tool_hat minus the tracker's p_tool_meas at the filters'
    instants (the tracker's stamps fall on them)."""
    from orchestration.study import simulate
    sc, filters, plant = study_montecarlo._scenario_parts(str(REALISTIC), REALISTIC_SHORT)
    run = study_montecarlo.run_one(str(REALISTIC), REALISTIC_SHORT + ["scenario.seed=1"], filters, plant,
                                   filters[0].ratio, "tracker")
    r = simulate(str(REALISTIC), REALISTIC_SHORT + ["scenario.seed=1"],
                 ["ekf_acc.p_tool_hat", "tracker.p_tool_meas", "tracker.t_meas"])
    idx = np.arange(1, len(r.time), filters[0].ratio)
    assert_allclose(r["tracker.t_meas"][idx].reshape(-1), r.time[idx], atol=1e-12)
    assert_allclose(run["ekf_acc.tool_reference"], r["ekf_acc.p_tool_hat"][idx] - r["tracker.p_tool_meas"][idx],
                    rtol=0, atol=0)
