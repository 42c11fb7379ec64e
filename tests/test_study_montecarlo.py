"""Tests of orchestration.study_montecarlo (the 2012 paper's Monte Carlo study, Fig. 3, Table 1).

The FMUs come from dist/fmus (``flexfusion build``), as for every scenario run.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import cli, study, study_montecarlo
from orchestration.scenario import DEFAULT_FMU_DIR

SCENARIO = Path(study_montecarlo.__file__).resolve().parent / "scenarios" / "axelsson2012.toml"
SHORT = ["scenario.stop_time=0.5"]

pytestmark = pytest.mark.skipif(not (DEFAULT_FMU_DIR / "EkfAccelerometer.fmu").exists(),
                                reason="needs the built FMUs in dist/fmus (flexfusion build)")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc1")
    data = study_montecarlo.run_study(SCENARIO, 3, out, SHORT, workers=1, progress=False, after=0.2)
    return out, data


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
                     "--set", SHORT[0]])
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


def test_same_numbers_on_a_dask_local_cluster(small, tmp_path):
    pytest.importorskip("distributed")
    _, one = small
    dask = study_montecarlo.run_study(SCENARIO, 3, tmp_path, SHORT, workers=2, scheduler="local",
                                      progress=False, after=0.2, plots=False)
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


@pytest.fixture(scope="module")
def study_100(tmp_path_factory):
    return study_montecarlo.run_study(SCENARIO, 100, tmp_path_factory.mktemp("mc100"), progress=False)["summary"]


@pytest.mark.slow
def test_section4_accelerometer_gains_over_100_runs(study_100):
    """Table 1's finding: the accelerometer lowers the angle RMSE by >= 30 %, the velocity RMSE
    by >= 3x and the acceleration RMSE by >= 2x (paper: 43 %, 5.4x, 3.2x)."""
    acc, mot = study_100["ekf_acc"], study_100["ekf_motor"]
    assert acc["rmse_position"] <= 0.7 * mot["rmse_position"]
    assert mot["rmse_velocity"] >= 3.0 * acc["rmse_velocity"]
    assert mot["rmse_acceleration"] >= 2.0 * acc["rmse_acceleration"]


@pytest.mark.slow
def test_section4_ekf_attains_its_own_models_bound_with_the_accelerometer(study_100):
    """The bound of DESIGN.md (the models the EKF uses): the EKF with accelerometer is within
    1.5x of it and not below it."""
    acc = study_100["ekf_acc"]
    assert acc["ekf_model_bound_position"] <= acc["rmse_position"] <= 1.5 * acc["ekf_model_bound_position"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="not reached: 20 runs give 3.5x (with) and 5.5x (without "
                   "accelerometer) the paper's physical-model CRLB, which takes the motor velocity "
                   "as exactly known, and the motor-only EKF is 0.90x its own model's bound (the "
                   "plant's jerk deviations are smaller than q_jerk assumes)")
def test_section4_ekf_within_1_5x_of_the_crlb_with_and_without_accelerometer(study_100):
    """The issue's criterion on the paper's bound (eqs. 21-25), with and without accelerometer."""
    for f in (study_100["ekf_acc"], study_100["ekf_motor"]):
        assert f["crlb_position"] <= f["rmse_position"] <= 1.5 * f["crlb_position"]
        assert f["ekf_model_bound_position"] <= f["rmse_position"]


@pytest.mark.skipif(not (DEFAULT_FMU_DIR / "ParticleFilter.fmu").exists(), reason="needs ParticleFilter.fmu")
def test_particle_filter_scenario_gives_fig4(tmp_path):
    pf = SCENARIO.with_name("axelsson2012_pf.toml")
    d = study_montecarlo.run_study(pf, 2, tmp_path, ["scenario.stop_time=0.2", "pf_prior.n_particles=100",
                                                     "pf_ekf.n_particles=100"],
                                   workers=1, progress=False, after=0.05)
    assert (tmp_path / "fig4.png").stat().st_size > 0
    assert set(d["pf_vs_ekf"]) == {"pf_prior", "pf_ekf"}
    for name in ("pf_prior", "pf_ekf"):
        v = d["pf_vs_ekf"][name]
        assert v["ekf"] == "ekf_acc"
        assert_allclose(v["position_ratio"], d["summary"][name]["rmse_position"]
                        / d["summary"]["ekf_acc"]["rmse_position"])
