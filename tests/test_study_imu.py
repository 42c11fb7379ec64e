"""The IMU study (`flexfusion study imu`): Table 1, findings, figures; the paper's findings on
the ISO path (slow)."""
import argparse
import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study_imu
from orchestration.scenario import scenario_document


def fake_run(n=200, fk=1e-3, cf=0.5e-3, ekf=0.6e-3, cf_paper=1.1e-3, cf_same=0.7e-3):
    t = np.arange(n) * 0.01
    truth = np.column_stack([np.linspace(1.0, 1.1, n), np.full(n, 0.6)])
    unit = np.column_stack([np.cos(t), np.sin(t)])       # errors of constant norm
    return {"time": t, "plant.p_tool": truth, "plant.a_tool": np.zeros((n, 2)),
            "rigid.p_tool_hat": truth + fk * unit, "cf.p_tool_hat": truth + cf * unit,
            "ekf.p_tool_hat": truth + ekf * unit, "cf_paper.p_tool_hat": truth + cf_paper * unit,
            "cf_same.p_tool_hat": truth + cf_same * unit}


#: Table 1 of the IMU paper as printed (the project never reads the paper: typed here, from
#: "Table 1. Root mean square error for the test trajectories and estimation methods.").
PAPER_TABLE1_TEXT = """Trajectory CF EKF FK
ISO 0.95 mm 0.94 mm 1.44 mm
Cube 0.81 mm 0.93 mm 0.79 mm"""


def test_paper_values_in_the_code_are_the_papers_table1():
    """The study's copy of Table 1 is the transcript above (PAPER_TABLE1_TEXT, checked by hand
    against the paper's Table 1 on 2026-11-30)."""
    head, *rows = PAPER_TABLE1_TEXT.splitlines()
    columns = {"CF": "cf_paper", "EKF": "ekf", "FK": "fk"}
    names = head.split()[1:]
    for row, path in zip(rows, ("iso", "square")):
        values = [float(v) * 1e-3 for v in row.split()[1::2]]
        expected = {columns[n]: v for n, v in zip(names, values)}
        assert study_imu.PAPER_TABLE1[path] == pytest.approx(expected, rel=1e-12)


def test_table1_against_a_sampled_skewed_reference():
    """Against a judge with stamps only its fresh samples count, at their stamps: a tracker at
    half the record's rate that is exactly the estimate delayed by one of its samples gives the
    RMSE of that delay, not of the hold."""
    from orchestration.judge import Judge
    t = np.arange(0.0, 2.0, 0.001)
    p = np.column_stack([0.1 * t, 0.05 * t])             # 0.1118 m/s
    stamp = np.floor(t / 0.002 + 1e-9) * 0.002           # 500 Hz, held
    meas = np.column_stack([0.1 * (stamp - 0.002), 0.05 * (stamp - 0.002)])   # 2 ms behind
    run = {"time": t, "tracker.p_tool_meas": meas, "tracker.t_meas": stamp, "plant.p_tool": p,
           **{v: p for v in study_imu.ESTIMATES.values()}}
    j = Judge("reference", "tracker", "tracker.p_tool_meas", "tracker.t_meas", "Tracker")
    table = study_imu.table1({"iso": run}, judge=j)
    assert_allclose(table["iso"]["ekf"], 0.002 * np.hypot(0.1, 0.05), rtol=1e-9)
    assert_allclose(study_imu.table1({"iso": run})["iso"]["ekf"], 0.0, atol=1e-15)


def test_table1_and_findings_from_series():
    table = study_imu.table1({"iso": fake_run(), "square": fake_run(fk=0.8e-3, cf_paper=0.82e-3, ekf=0.9e-3)})
    assert_allclose(table["iso"]["fk"], 1e-3, rtol=1e-12)
    assert_allclose(table["iso"]["cf_paper"], 1.1e-3, rtol=1e-12)
    assert list(table["iso"]) == ["cf_paper", "ekf", "fk", "cf", "cf_same"]   # the paper's first
    f = study_imu.findings(table)
    assert all(set(x) == {"claim", "ours", "reproduced", "why"} for x in f)
    assert all(x["reproduced"] in ("yes", "no") for x in f)
    by_claim = {x["claim"].split(" (")[0]: x for x in f}
    # ISO: the paper's CF (1.1 mm) does not beat FK (1.0 mm); the square: FK 0.8 vs CF 0.82 within 10 %
    assert by_claim["On the ISO path both filters beat forward kinematics"]["reproduced"] == "no"
    assert by_claim["On the ISO path both filters beat forward kinematics"]["why"]
    assert by_claim["On the slow square"]["reproduced"] == "yes"
    assert by_claim["The CF is slightly better than the EKF on the slower trajectory"]["reproduced"] == "yes"
    text = study_imu.format_table(table)
    assert "1.100 mm" in text and "1.44 mm" in text and "0.79 mm" in text


def test_figures_are_written(tmp_path):
    files = study_imu.plot_figures({"iso": fake_run(), "square": fake_run()}, tmp_path)
    names = sorted(f.name for f in files)
    assert names == ["fig2_iso_path.png", "fig4_square_path.png", "fig5_iso_error.png",
                     "fig6_square_error.png"]
    assert all(f.stat().st_size > 10_000 for f in files)


def test_cli_registration():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    study_imu.register(sub)
    args = parser.parse_args(["imu", "--out", "x", "--stop-time", "1.5", "--workers", "2"])
    assert args.func is study_imu.main and args.stop_time == 1.5 and args.workers == 2


def test_short_study_run(fmu_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    res = study_imu.run_study(tmp_path, stop_time=0.8, workers=2, progress=False)
    for path in ("iso", "square"):
        row = res["table1"][path]
        assert list(row) == list(study_imu.ESTIMATES)
        assert all(np.isfinite(v) and 0 < v < 0.01 for v in row.values())
    for name in ("table1.md", "table1.csv", "metrics.json", "fig2_iso_path.png", "fig5_iso_error.png",
                 "fig6_square_error.png"):
        assert (tmp_path / name).exists(), name
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert set(saved) >= {"table1", "paper_table1", "labels", "findings", "wall_time", "figures"}
    assert saved["paper_table1"] == study_imu.PAPER_TABLE1
    assert saved["wall_time"]["workers"] == 2 and saved["wall_time"]["total_s"] > 0
    assert len(saved["findings"]) == 6
    # judged by the reference system (the scenarios' tracker) by default, the truth beside it
    assert saved["against"] == "reference"
    assert saved["judge"] == {"against": "reference", "component": "tracker", "fmu": "Tracker",
                              "variable": "tracker.p_tool_meas", "stamp": "tracker.t_meas"}
    assert list(saved["table1_truth"]["iso"]) == list(study_imu.ESTIMATES)
    assert saved["table1"]["iso"]["ekf"] != saved["table1_truth"]["iso"]["ekf"]
    # the scenario's own metrics (against the truth) are the study's truth column
    assert_allclose(res["metrics"]["iso"]["cf_rmse"], res["table1_truth"]["iso"]["cf"], rtol=1e-9)


def test_tuning_goes_through_the_shared_tuner(fmu_dir, tmp_path, monkeypatch):
    """One generation of a tiny population on a short run: the include file is what the
    scenarios read, the values inside the bounds."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    res = study_imu.tune_filters(tmp_path, maxiter=1, popsize=1, workers=2, progress=False,
                                 stop_time=0.8, only=["cf_same"], holdout_seeds=(3,))
    p = res["cf_same"]["params"]
    bounds = study_imu.tuned_bounds("cf_same")
    assert set(p) == set(bounds) == {"cutoff", "damping"}
    for name, (lo, hi) in bounds.items():
        assert lo <= p[name] <= hi
    assert res["seeds"] == [2] and res["holdout_seeds"] == [3]
    assert res["cf_same"]["against"] == "reference" and res["cf_same"]["judge"]["component"] == "tracker"
    assert 0 < res["cf_same"]["holdout_rmse"] < 0.01
    import tomllib
    doc = tomllib.loads((tmp_path / "imu2019_tuned.toml").read_text())
    assert doc["components"]["cf_same"]["parameters"] == pytest.approx(p)


def test_cli_tunes_several_estimators_in_one_call(fmu_dir, tmp_path, monkeypatch, capsys):
    """`flexfusion study tune` with the CF and the IMU EKF in one call, at a tiny budget (one
    generation of the smallest population, 0.8 s runs): each estimator gets its FMU type's
    default bounds, its own include file naming the exact command, and its JSON with the
    training and held-out costs."""
    import tomllib

    from orchestration import cli, study_tune
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    code = cli.main(["study", "tune", str(study_imu.PATHS["iso"]), "--estimator", "cf",
                     "--estimator", "ekf", "--out", str(tmp_path), "--maxiter", "1", "--popsize", "1",
                     "--stop-time", "0.8", "--seeds", "2", "--holdout-seeds", "3", "--workers", "2",
                     "--no-progress"])
    assert code == 0
    printed = capsys.readouterr().out
    for comp, kind in (("cf", "ComplementaryFilter"), ("ekf", "ImuEkf")):
        res = json.loads((tmp_path / f"tune_{comp}.json").read_text())
        bounds = study_tune.default_bounds(scenario_document(study_imu.PATHS["iso"]), comp)
        assert set(res["params"]) == set(bounds)
        for name, value in res["params"].items():
            assert bounds[name][0] <= value <= bounds[name][1], (comp, name)
        assert res["seeds"] == [2] and res["holdout_seeds"] == [3] and res["failed"] == 0
        assert res["against"] == "reference" and res["judge"]["component"] == "tracker"   # the default judge
        assert res["n_evals"] == len(res["history"]) == 2 * 5       # scipy's smallest population: 5
        assert 0 < res["cost"] < 0.01 and 0 < res["holdout_cost"] < 0.01
        assert res["cost"] == pytest.approx(min(h["cost"] for h in res["history"]))
        text = (tmp_path / f"tuned_{comp}.toml").read_text()
        assert f"--estimator {comp} " in text and "--seeds 2 --holdout-seeds 3" in text
        assert tomllib.loads(text)["components"][comp]["parameters"] == pytest.approx(res["params"])
        assert f"{comp}: cost" in printed


@pytest.mark.slow
def test_paper_findings_on_the_iso_path(fmu_dir, tmp_path, monkeypatch):
    """What we claim on the ISO path (full length, the shipped tuning): the EKF beats forward
    kinematics by >= 20 % RMSE (paper: 35 %); the paper's CF, one split at 28 Hz, does not
    (it passes FK's errors below 28 Hz: the arm's vibration and the static kinematic errors);
    our tuned two-split CF does."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    res = study_imu.run_study(tmp_path, workers=2, progress=False, paths=("iso",))
    row = res["table1"]["iso"]
    assert 1 - row["ekf"] / row["fk"] >= 0.2, row
    assert 1 - row["cf_paper"] / row["fk"] < 0.2, row
    assert 1 - row["cf"] / row["fk"] >= 0.2, row
