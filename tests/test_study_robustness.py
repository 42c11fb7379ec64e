"""study_robustness: Table I of Henriksson et al. (2009) on short runs (fast), and the paper's
findings on the full runs (slow)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study, study_robustness as sr
from orchestration.cli import main
from orchestration.scenario import scenario_document
from references import STUDY_RTOL, assert_same_document
from toys import with_third_party


def test_jobs_give_only_the_estimators_the_model_errors(fmu_env) -> None:
    """Each case's estimators take the identified set with its error; the controller keeps the
    identified set; joint 2 only changes joint 2; the identification error is 5 % on each
    identified parameter and nothing else."""
    jobs = sr.case_jobs(stop_time=1.0)
    assert [c[0] for c in sr.CASES] == ["nominal", "tuning", "model_errors", "model_errors_joint2",
                                        "ident_errors"]
    assert len(jobs) == len(sr.CASES)
    for (doc, overrides, variables), (key, _, _, error) in zip(jobs, sr.CASES):
        est = sr.estimators(doc)
        assert "rigid" in est and "observer" in est and len(est) == 7
        assert variables[:10] == (["plant.p_tool", "tracker.p_tool_meas", "tracker.t_meas"]   # truth, judge
                                  + [f"{c}.p_tool_hat" for c in est])
        assert {"ekf_motor.q_a_hat", "ekf_motor.ddq_a_hat", "observer.dq_a_hat", "rigid.q_a_hat",
                "plant.q_a", "plant.dq_a", "plant.ddq_a"} <= set(variables[8:])
        assert overrides == ["scenario.stop_time=1.0"]
        assert doc["components"]["controller"]["parameter_sets"] == [sr.MODEL_SET]
        true_set = doc["parameter_sets"][sr.MODEL_SET]
        if not error:
            assert all(doc["components"][c]["parameter_sets"] == [sr.MODEL_SET] for c in est)
            continue
        sname = f"{sr.MODEL_SET}_{error}"
        assert all(doc["components"][c]["parameter_sets"] == [sname] for c in est)
        wrong = doc["parameter_sets"][sname]
        ratio = {k: np.asarray(wrong[k], float) / np.asarray(true_set[k], float) for k in true_set}
        changed = {k for k, r in ratio.items() if not np.allclose(r, 1.0)}
        if error == "stiffness_50":
            assert changed == {"k_lo", "k_hi"}
            assert_allclose(ratio["k_lo"], [0.5, 0.5]) and assert_allclose(ratio["k_hi"], [0.5, 0.5])
        elif error == "stiffness_50_joint2":
            assert changed == {"k_lo", "k_hi"}
            assert_allclose(ratio["k_lo"], [1.0, 0.5]) and assert_allclose(ratio["k_hi"], [1.0, 0.5])
        else:
            assert changed == set(sr.IDENTIFIED)
            for k in changed:
                assert_allclose(np.abs(ratio[k] - 1.0), sr.IDENT_ERROR, rtol=1e-9)


#: Table I of Henriksson et al. 2009 as printed (transcribed; the test must not read the paper):
#: case, band, then max / mean for EKF Complete, EKF Motor, EKF Integrated, Det. Observer, Rigid.
TABLE_I_TEXT = """
Nominal      All     17.6  9.7   16.2  7.2   174.3 101.0 97.0  59.9  5.6   2.7
Nominal      3-30Hz  1.007 0.070 0.914 0.111 1.114 0.056 1.121 0.057 2.142 0.221
Tuning       All     9.4   7.2   16.3  6.0   82.0  36.4  43.3  28.6  2.1   0.5
Tuning       3-30Hz  0.135 0.027 0.698 0.122 0.110 0.018 0.108 0.020 1.351 0.219
ModelErrors  All     24.0  16.3  24.0  13.2  163.3 94.3  69.8  45.4  5.6   2.7
ModelErrors  3-30Hz  1.070 0.090 2.803 0.340 1.113 0.056 1.120 0.057 2.142 0.221
"""


def test_paper_table_is_the_papers() -> None:
    """PAPER_TABLE holds Table I's 60 numbers (TABLE_I_TEXT checked by hand, number by number,
    against the paper's Table I on 2026-11-30), and they give the paper's own prose figures
    (section IV-C): mean error 2 %, 25 %, 98 % above EKF Integrated's on P1, 11 %, 50 %, 580 % on
    P2; +206 % (EKF Motor) and +29 % (EKF Complete) with the stiffness error."""
    cols = ["EKF Complete", "EKF Motor", "EKF Integrated", "Det. Observer", "Rigid kinematics"]
    keys = {"Nominal": "nominal", "Tuning": "tuning", "ModelErrors": "model_errors"}
    rows = [line.split() for line in TABLE_I_TEXT.strip().splitlines()]
    assert len(rows) == 6
    assert set(sr.PAPER_TABLE) == set(keys.values())
    for case, band, *nums in rows:
        off = 0 if band == "All" else 2
        for i, col in enumerate(cols):
            assert sr.PAPER_TABLE[keys[case]][col][off:off + 2] == (float(nums[2 * i]), float(nums[2 * i + 1]))
    mean = {k: {c: v[3] for c, v in t.items()} for k, t in sr.PAPER_TABLE.items()}
    for key, pct in (("nominal", (2, 25, 98)), ("tuning", (11, 50, 580))):
        got = [100 * (mean[key][c] / mean[key]["EKF Integrated"] - 1)
               for c in ("Det. Observer", "EKF Complete", "EKF Motor")]
        assert_allclose(got, pct, atol=2.5)
    assert_allclose(100 * (mean["model_errors"]["EKF Motor"] / mean["nominal"]["EKF Motor"] - 1), 206, atol=1)
    assert_allclose(100 * (mean["model_errors"]["EKF Complete"] / mean["nominal"]["EKF Complete"] - 1), 29, atol=1)


def test_error_stats_of_a_known_error() -> None:
    """A 10 Hz sine error of amplitude 1 mm on x plus a 5 mm offset: all frequencies max 6 mm,
    mean 5 mm; the band-pass removes the offset and passes the sine (mean 2/pi mm)."""
    t = np.arange(0.0, 4.0, 5e-4)
    truth = np.zeros((len(t), 2))
    est = np.column_stack([5e-3 + 1e-3 * np.sin(2 * np.pi * 10 * t), np.zeros_like(t)])
    s = sr.error_stats(t, est, truth, after=0.5)
    assert s["all_max"] == pytest.approx(6e-3, rel=1e-6)
    assert s["all_mean"] == pytest.approx(5e-3, rel=1e-3)
    assert s["band_max"] == pytest.approx(1e-3, rel=0.02)
    assert s["band_mean"] == pytest.approx(2e-3 / np.pi, rel=0.02)


REFERENCE = Path(__file__).parent / "data" / "robustness_main_reference.json"


def short_table() -> dict:
    """The paper's table at 0.3 s on the batched engine (the table of these tests)."""
    return sr.robustness(stop_time=0.3, after=0.05, progress=False, workers=1, engine="batched")


def comparable(table_json: Path) -> dict:
    """table.json without what changes from run to run (wall times, workers, the engine's
    report) and the arm estimates' errors (not in the first recording)."""
    js = json.loads(table_json.read_text())
    for case in js["cases"].values():
        case.pop("wall_time")
        case.pop("arm_errors")
    js.pop("wall_time"), js.pop("workers"), js.pop("engine")
    return js


def save() -> None:
    """Re-record :data:`REFERENCE` from the working tree (``python tests/references.py robustness``)."""
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        sr.write(short_table(), Path(tmp))
        table = comparable(Path(tmp) / "table.json")
    REFERENCE.write_text(json.dumps({"how": "short_table() of tests/test_study_robustness.py, written by sr.write() "
                                            "and its save() (python tests/references.py robustness): table.json "
                                            "without wall times, workers, the engine and the arm errors",
                                     "table": table}, indent=1) + "\n")


def test_short_robustness_table(fmu_env, tmp_path) -> None:
    """The paper's table at 0.3 s: what it holds, and table.json is its stored reference
    (tests/data/robustness_main_reference.json, first recorded from main before the generic
    studies; tests/references.py) but for the arm estimates' errors, which it did not have."""
    table = short_table()
    # on the batched engine: P1's truth simulated once, P2's once, the model errors
    # played back on P1's; a taped and a replayed case identical to their FMU runs (and every
    # case to main's FMU table, below)
    eng = table["engine"]
    assert eng["used"] == "batched" and eng["taped"] == ["nominal", "tuning"]
    assert eng["replayed"] == ["model_errors", "model_errors_joint2", "ident_errors"]
    assert eng["checked_cases"] == ["nominal", "model_errors"] and eng["max_relative_difference"] <= study.CHECK_RTOL
    cases = table["cases"]
    assert list(cases) == [c[0] for c in sr.CASES]
    for case in cases.values():
        assert "Rigid kinematics" in case["columns"] and "Det. Observer" in case["columns"]
        for st in case["columns"].values():
            assert set(st) == set(sr.STATS) and all(np.isfinite(v) and v >= 0 for v in st.values())
    # rigid kinematics (no gravity compensation) uses no dynamic parameter: unchanged by every
    # model error; the observers are not
    for key in ("model_errors", "model_errors_joint2", "ident_errors"):
        assert cases[key]["columns"]["Rigid kinematics"] == cases["nominal"]["columns"]["Rigid kinematics"]
        assert cases[key]["columns"]["EKF Motor"] != cases["nominal"]["columns"]["EKF Motor"]
    files = sr.write(table, tmp_path)
    names = {f.name for f in files}
    assert {"table.json", "table.md", "fig4_nominal.png", "fig5_tuning.png", "fig6_model_errors.png"} <= names
    js = json.loads((tmp_path / "table.json").read_text())
    assert js["paper"] == {k: {c: list(v) for c, v in t.items()} for k, t in sr.PAPER_TABLE.items()}
    assert js["paper"]["nominal"]["Rigid kinematics"] == [5.6, 2.7, 2.142, 0.221]
    assert js["wall_time"] > 0 and js["workers"] == 1
    assert len(js["findings"]) == 4
    for f in js["findings"]:
        assert set(f) >= {"claim", "paper", "ours", "reproduced", "why"} and isinstance(f["reproduced"], bool)
    assert js["findings"][3]["paper"]["EKF Motor"] == pytest.approx(2.063, abs=1e-3)
    md = (tmp_path / "table.md").read_text()
    assert "(0.221)" in md and "Model errors" in md and "Findings" in md
    arm = [case["arm_errors"] for case in js["cases"].values()]
    assert set(arm[0]["EKF Motor"]) == {"q_a_hat", "dq_a_hat", "ddq_a_hat"} and set(arm[0]["Rigid kinematics"]) == {"q_a_hat"}
    # judged by the reference system (the tracker) by default; the truth's statistics beside
    assert js["against"] == "reference"
    assert js["judge"] == {"against": "reference", "component": "tracker", "fmu": "Tracker",
                           "variable": "tracker.p_tool_meas", "stamp": "tracker.t_meas"}
    assert "against the reference system" in md and "against the plant's truth" in md
    for case in js["cases"].values():
        assert case["columns"] != case["columns_truth"]
        assert set(case["columns"]) == set(case["columns_truth"])
    assert_same_document(comparable(tmp_path / "table.json"), json.loads(REFERENCE.read_text())["table"], STUDY_RTOL,
                         {"band_max": "all_max", "band_mean": "all_max"})


def test_a_difference_from_the_fmus_stops_the_study(fmu_env, monkeypatch) -> None:
    """A batched estimate off by 1e-9 relative stops the study, naming the case, the series
    and the difference; --engine fmu runs no batched case."""
    batched_case = sr._batched_case

    def off(job, tape, replay=None):
        res, taped = batched_case(job, tape, replay)
        res["observer.p_tool_hat"] = res["observer.p_tool_hat"] * (1 + 1e-9)
        return res, taped

    monkeypatch.setattr(sr, "_batched_case", off)
    nominal = sr.CASES[:1]
    with pytest.raises(study.StudyError, match=r"case 'nominal': observer.p_tool_hat differs by 1e-09 relative "
                                               r".*--engine fmu"):
        sr.robustness(stop_time=0.1, after=0.05, progress=False, cases=nominal, engine="batched")
    assert sr.robustness(stop_time=0.1, after=0.05, progress=False, cases=nominal, engine="fmu")["engine"] == {
        "used": "fmu"}


def test_runs_shorter_than_the_left_out_start_are_one_error(tmp_path, capsys) -> None:
    from orchestration import cli
    assert cli.main(["study", "robustness", "--stop-time", "0.3", "--out", str(tmp_path),
                     "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--stop-time 0.3 s" in err[0]


@pytest.fixture(scope="module")
def toy_scenarios(tmp_path_factory, third_party_fmus) -> dict[str, Path]:
    """P1 with the third-party estimator ``toy`` fed by the encoder, and with ``leaky`` too,
    which misses the contract."""
    folder = tmp_path_factory.mktemp("robust_toy")
    ok = with_third_party(sr.SCENARIOS / "henriksson2009_p1.toml", third_party_fmus, folder / "p1_toy.toml")
    leaky = with_third_party(ok, third_party_fmus, folder / "p1_leaky.toml", "leaky", "LeakyEstimator", source="")
    return {"ok": ok, "leaky": leaky}


def _robustness(out: Path, *extra: str) -> int:
    return main(["study", "robustness", "--stop-time", "0.7", "--workers", "1", "--no-progress", "--out", str(out),
                 *extra])


def test_a_third_party_estimator_beside_ours(fmu_env, toy_scenarios, tmp_path, capsys) -> None:
    """The robustness cases on any scenario with any estimator: the toy's column is its
    component's name, and its errors are those of a plain run of the scenario (computed here);
    the model errors reach our EKF Motor, not the toy (its model is its own); without the
    paper's five columns there are no findings; no tuning case without --other-path."""
    out = tmp_path / "robust"
    assert _robustness(out, "--scenario", str(toy_scenarios["ok"]), "--estimator", "ekf_motor",
                       "--estimator", "toy") == 0
    assert "toy" in capsys.readouterr().out
    js = json.loads((out / "table.json").read_text())
    cases = js["cases"]
    assert list(cases) == ["nominal", "model_errors", "model_errors_joint2", "ident_errors"]
    assert js["findings"] == [] and "skipped" not in js
    for case in cases.values():
        assert list(case["columns"]) == ["EKF Motor", "toy"]
        assert case["columns"]["toy"] == cases["nominal"]["columns"]["toy"]
        assert case["arm_errors"]["toy"] == {} and set(case["arm_errors"]["EKF Motor"]) == {"q_a_hat", "dq_a_hat", "ddq_a_hat"}
    assert cases["model_errors"]["columns"]["EKF Motor"] != cases["nominal"]["columns"]["EKF Motor"]
    doc = scenario_document(toy_scenarios["ok"])
    doc["record"]["variables"] = ["plant.p_tool", "plant.q_a", "toy.p_tool_hat", "ekf_motor.q_a_hat",
                                  "tracker.p_tool_meas", "tracker.t_meas"]
    r = study.simulate(doc, ["scenario.stop_time=0.7"])
    keep = r.time >= 0.5 - 1e-12
    e = np.linalg.norm(r["toy.p_tool_hat"] - r["plant.p_tool"], axis=1)[keep]
    assert_allclose([cases["nominal"]["columns_truth"]["toy"][k] for k in ("all_max", "all_mean")], [e.max(), e.mean()],
                    rtol=1e-12)
    # the judged column: against the tracker's fresh samples at their stamps
    from orchestration.metrics import at_sample_times
    t, est, ref = at_sample_times(r.time, r["toy.p_tool_hat"], r["tracker.p_tool_meas"], r["tracker.t_meas"])
    e = np.linalg.norm(est - ref, axis=1)[t >= 0.5 - 1e-12]
    assert js["against"] == "reference"
    assert_allclose([cases["nominal"]["columns"]["toy"][k] for k in ("all_max", "all_mean")], [e.max(), e.mean()],
                    rtol=1e-12)
    q = r["ekf_motor.q_a_hat"][keep] - r["plant.q_a"][keep]
    assert_allclose(cases["nominal"]["arm_errors"]["EKF Motor"]["q_a_hat"]["rmse"],
                    np.sqrt(np.mean(np.sum(q * q, axis=1))), rtol=1e-12)
    assert (out / "fig4_nominal.png").stat().st_size > 0


def test_a_model_error_no_studied_estimator_takes_is_left_out_and_said(fmu_env, toy_scenarios, tmp_path,
                                                                       capsys) -> None:
    out = tmp_path / "toy_only"
    assert _robustness(out, "--scenario", str(toy_scenarios["ok"]), "--other-path",
                       str(toy_scenarios["ok"]), "--estimator", "toy", "--engine", "batched") == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["robustness: the batched engine knows only the math of our FMUs, and 'toy' "
                   "(ThirdPartyEstimator) is not one of them: every case runs through the FMUs"] + [
        f"robustness: case '{k}' left out: no studied estimator takes the parameter set "
        "'identified_robot' the model error is put in" for k in ("model_errors", "model_errors_joint2", "ident_errors")]
    js = json.loads((out / "table.json").read_text())
    assert list(js["cases"]) == ["nominal", "tuning"] and set(js["skipped"]) == {
        "model_errors", "model_errors_joint2", "ident_errors"}


@pytest.mark.parametrize("name, message", [
    ("nosuch", r"^error: --estimator nosuch: scenario 'henriksson2009_p1' has no component 'nosuch' \(components: .*toy.*\)$"),
    ("leaky", r"^error: --estimator leaky: LeakyEstimator.fmu does not meet the estimator contract "
              r".*required-outputs: p_tool_hat\[1\] \(missing\).*$"),
])
def test_a_bad_or_non_contract_estimator_is_one_line_and_exit_2(fmu_env, toy_scenarios, tmp_path, capsys,
                                                                name, message) -> None:
    assert _robustness(tmp_path / "bad", "--scenario", str(toy_scenarios["leaky"]), "--estimator", "toy",
                       "--estimator", name) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.match(message, err[0]), err
    assert not list((tmp_path / "bad" / "jobs").glob("*.pickle"))


#: Reduced size of the slow test: the first 3 s of P1 and P2 (the full paths are 8 and 6.5 s),
#: with P1's hammer strike (1.5-1.7 s) and the start of each path's motion.
REDUCED_STOP_TIME = 3.0


@pytest.mark.slow
def test_the_papers_findings(fmu_env, tmp_path) -> None:
    """The study at reduced size (every case, the shipped P1-tuned scenarios, the first
    :data:`REDUCED_STOP_TIME` s, as `flexfusion study robustness --stop-time 3 --workers 2`:
    128 s on 2 workers of a busy machine, 8 min under heavy load; the full study 239 s). Asserted, as docs/figures.md and the findings claim: the one paper
    finding we reproduce, every accelerometer-based observer (and our variants) at least 2x (the
    paper's lower factor) below rigid kinematics' 3-30 Hz mean error on P1 and P2 (measured at
    this size 5.1-14x; full size 5.3-13x); the three we do not reproduce stay not reproduced
    (EKF Motor beaten by the accelerometer observers; EKF Motor the worst; EKF Integrated and the
    observer unaffected by the 50 % stiffness error); beyond the paper, the drift-corrected EKF
    Integrated below rigid kinematics' error at all frequencies (mean) in every case, model
    errors included."""
    from orchestration.study import open_executor
    with open_executor(workers=2) as ex:
        table = sr.robustness(executor=ex, progress=False, workers=2, stop_time=REDUCED_STOP_TIME)
    sr.write(table, tmp_path)
    cases = table["cases"]
    claims = [f["claim"] for f in table["findings"]]
    assert claims[0].startswith("accelerometer-based observers beat rigid kinematics")
    assert claims[1].startswith("accelerometer-based observers beat EKF Motor")
    assert claims[2].startswith("EKF Motor is the worst observer")
    assert claims[3].startswith("with the 50 % stiffness error")
    assert [f["reproduced"] for f in table["findings"]] == [True, False, False, False]
    for key in ("nominal", "tuning"):
        cols = cases[key]["columns"]
        acc = [c for c in cols if sr.base_label(c) in sr.ACC_BASED]
        assert len(acc) == 5
        for c in acc:
            assert cols[c]["band_mean"] <= cols["Rigid kinematics"]["band_mean"] / 2, (key, c)
    for key, case in cases.items():
        fixed = next(c for c in case["columns"] if "drift correction" in c)
        assert case["columns"][fixed]["all_mean"] < case["columns"]["Rigid kinematics"]["all_mean"], key
