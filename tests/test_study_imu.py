"""The IMU study (`flexfusion study imu`): Table 1, findings, figures; the paper's findings on
the ISO path (slow)."""
import argparse

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study_imu

FMUS = ["MotionController", "FlexibleRobot2DOF", "Encoder", "Imu", "RigidKinematics",
        "ComplementaryFilter", "ImuEkf"]


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory):
    from orchestration.build import build_all
    dest = tmp_path_factory.mktemp("imu_study_fmus")
    build_all(dest, only=FMUS, quiet=True)
    return dest


def fake_run(n=200, fk=1e-3, cf=0.5e-3, ekf=0.6e-3, cf_paper=1.1e-3, cf_same=0.7e-3):
    t = np.arange(n) * 0.01
    truth = np.column_stack([np.linspace(1.0, 1.1, n), np.full(n, 0.6)])
    unit = np.column_stack([np.cos(t), np.sin(t)])       # errors of constant norm
    return {"time": t, "plant.p_tool": truth, "plant.a_tool": np.zeros((n, 2)),
            "rigid.p_tool_hat": truth + fk * unit, "cf.p_tool_hat": truth + cf * unit,
            "ekf.p_tool_hat": truth + ekf * unit, "cf_paper.p_tool_hat": truth + cf_paper * unit,
            "cf_same.p_tool_hat": truth + cf_same * unit}


def test_table1_and_findings_from_series():
    table = study_imu.table1({"iso": fake_run(), "square": fake_run(fk=0.8e-3, cf=0.82e-3)})
    assert_allclose(table["iso"]["fk"], 1e-3, rtol=1e-12)
    assert_allclose(table["iso"]["cf"], 0.5e-3, rtol=1e-12)
    f = study_imu.findings(table)
    assert_allclose(f["iso"]["cf_gain_over_fk"], 0.5, rtol=1e-12)
    assert_allclose(f["iso"]["cf_vs_ekf"], 0.5 / 0.6 - 1, rtol=1e-12)
    assert f["iso_filters_beat_fk_by_20pct"] is True
    assert f["iso_cf_within_10pct_of_ekf"] is False
    text = study_imu.format_table(table)
    assert "0.500 mm" in text and "1.44 mm" in text


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
        assert set(row) == {"fk", "cf", "ekf", "cf_paper", "cf_same"}
        assert all(np.isfinite(v) and 0 < v < 0.01 for v in row.values())
    for name in ("table1.md", "table1.csv", "metrics.json", "fig2_iso_path.png", "fig5_iso_error.png",
                 "fig6_square_error.png"):
        assert (tmp_path / name).exists(), name
    # the scenario's own metrics are the study's numbers
    assert_allclose(res["metrics"]["iso"]["cf_rmse"], res["table1"]["iso"]["cf"], rtol=1e-9)


def test_replay_matches_the_cosimulation(fmu_dir, monkeypatch):
    """The tuning replays recorded inputs through the plain models: same estimate as the FMUs."""
    from fmus.common.parameters import replace
    from fmus.estimators import complementary_filter_model as cfm
    from orchestration.scenario import load_scenario
    from orchestration.study import simulate
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    run = simulate(study_imu.PATHS["square"], ["scenario.stop_time=0.6"])
    sc = load_scenario(study_imu.PATHS["square"])
    cf_params = {k: v for k, v in sc.components["cf"].parameters.items()
                 if k in ("cutoff", "damping", "cutoff_orientation")}
    est = study_imu.replay("cf", replace(cfm.ComplementaryFilterParameters(), **cf_params),
                           study_imu.replay_data(run))
    assert_allclose(est, run["cf.p_tool_hat"], atol=1e-13, rtol=0)


@pytest.mark.slow
def test_paper_findings_on_the_iso_path(fmu_dir, tmp_path, monkeypatch):
    """IMU paper, Table 1: on the ISO path both filters beat forward kinematics by >= 20 % RMSE
    (paper: 34 %). The paper's CF is within 1 % of its EKF; here the IMU keeps the residual
    mounting and scale errors of the paper's calibration (imu2019_iso.toml), which the EKF
    estimates as biases and the CF (no bias states, cut-offs tuned on an ideal IMU) does not:
    a 0.4 mrad pitch error is g 0.4e-3 = 4 mm/s2 of acceleration bias, b / (2 pi 0.68 Hz)^2 =
    0.2 mm of static position error. So the EKF is no worse than the CF."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(fmu_dir))
    res = study_imu.run_study(tmp_path, workers=2, progress=False, paths=("iso",))
    iso = res["findings"]["iso"]
    assert iso["cf_gain_over_fk"] >= 0.2, res["table1"]
    assert iso["ekf_gain_over_fk"] >= 0.2, res["table1"]
    assert iso["cf_vs_ekf"] >= 0.0, res["table1"]
