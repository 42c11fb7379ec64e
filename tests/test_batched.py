"""Tests of the batched study engine (orchestration.batched) and its kernels
(fmus.robot_plant.sensor_batched, fmus.estimators.ekf_accelerometer_batched): the same numbers
as the co-simulation of the FMUs."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from fmus.common.noise import make_rng
from orchestration import batched, study, study_montecarlo
from orchestration.scenario import scenario_document

pytestmark = pytest.mark.usefixtures("fmu_env_module")      # scenarios find every FMU of this test run

SCENARIO = Path(study_montecarlo.__file__).resolve().parent / "scenarios" / "axelsson2012.toml"
SHORT = ["scenario.stop_time=0.3"]

def test_run_streams_are_each_seeds_own_generator():
    """Run r's numbers are what the FMU with seed r draws, call by call, across block borders."""
    from fmus.robot_plant.sensor_batched import RunStreams
    seeds = [3, 7, 11]
    streams = RunStreams(seeds, "encoder/noise", block=3)
    got = np.stack([streams.standard_normal(2) for _ in range(7)])         # (calls, runs, 2)
    for r, s in enumerate(seeds):
        rng = make_rng(s, "encoder/noise")
        assert_array_equal(got[:, r], [rng.standard_normal(2) for _ in range(7)])


def test_batched_ekf_equals_the_single_filter():
    """BatchedEkfModel: each run's update and prediction are the single filter's, bit for bit
    (the same compiled kernels), also for runs that differ in q_jerk."""
    from fmus.estimators import ekf_accelerometer_model as em
    from fmus.estimators.ekf_accelerometer_batched import BatchedEkfModel
    base = em.EkfAccelerometerParameters(p_tool0=(1.2, 0.9))
    params = [base, em.EkfAccelerometerParameters(p_tool0=(1.2, 0.9), q_jerk=0.3)]
    model = BatchedEkfModel(params)
    rng = np.random.default_rng(4)
    singles = [em.EkfAccelerometerModel(p) for p in params]
    x = np.stack([s.x + 1e-3 * rng.standard_normal(6) for s in singles])
    P = np.stack([s.P for s in singles])
    y = np.stack([s.meas.h(xi) for s, xi in zip(singles, x)]) + 1e-3 * rng.standard_normal((2, 4))
    u = rng.standard_normal((2, 2))
    xf, Pf, nu = model.filtered(y, x, P)
    xp, Pp = model.predicted(u, 0.01, xf, Pf)
    for r, s in enumerate(singles):
        xs, Ps, ns = s.filtered(y[r], x[r], P[r])
        assert_array_equal(xf[r], xs)
        assert_array_equal(Pf[r], Ps)
        assert nu[r] == ns
        xq, Pq = s.predicted(u[r], 0.01, xs, Ps)
        assert_array_equal(xp[r], xq)
        assert_array_equal(Pp[r], Pq)
    with pytest.raises(ValueError, match="q_jerk only"):
        BatchedEkfModel([base, em.EkfAccelerometerParameters(r_acc=1.0)])


def test_batched_ekf_names_the_diverged_runs():
    """A run whose estimate is not finite stops the batch with the single filter's message,
    naming the run (0-based)."""
    from fmus.common.kalman import FilterDivergence
    from fmus.estimators import ekf_accelerometer_model as em
    from fmus.estimators.ekf_accelerometer_batched import BatchedEkfModel
    single = em.EkfAccelerometerModel(em.EkfAccelerometerParameters())
    model = BatchedEkfModel(single.p)
    x, P = np.stack([single.x] * 3), np.stack([single.P] * 3)
    x[1, 0] = np.nan
    y = np.stack([single.meas.h(single.x)] * 3)
    with pytest.raises(FilterDivergence, match=r"^EKF diverged in the measurement update: non-finite .*"
                                                r"\(runs \[1\]\)$"):
        model.filtered(y, x, P)
    P[2] = -P[2]
    with pytest.raises(FilterDivergence, match=r"^EKF diverged in the time update: .*\(runs \[1, 2\]\)$"):
        model.predicted(np.zeros((3, 2)), 0.01, x, P)


def test_batched_runs_equal_the_fmus():
    """Three seeds on the batched engine and through the FMUs: the same numbers, bit for bit
    (the shared closed loop runs the FMU classes' own code, the kernels repeat their math)."""
    sc, filters, plant = study_montecarlo._scenario_parts(str(SCENARIO), SHORT)
    seeds = [1, 2, 5]
    runs, res = study_montecarlo.run_batched(str(SCENARIO), [SHORT + [f"scenario.seed={s}"] for s in seeds],
                                             filters, plant, filters[0].ratio)
    assert res.shared == ["plant", "drive_encoder", "controller"] and res.looped == []   # the closed loop
    assert res.batched == ["encoder", "imu", "ekf_acc", "ekf_motor"]
    for s, b in zip(seeds, runs):
        f = study_montecarlo.run_one(str(SCENARIO), SHORT + [f"scenario.seed={s}"], filters, plant,
                                     filters[0].ratio)
        q = study_montecarlo.checked_quantities
        assert study.check_against_fmus(q(b, filters), q(f, filters), f"seed {s}") == 0.0
        for key in f:
            if key != "wall_time":
                assert_array_equal(b[key], f[key], err_msg=key)
    # different seeds, different noise
    assert not np.allclose(runs[0]["ekf_acc"], runs[1]["ekf_acc"])


def test_a_stop_time_the_filter_step_does_not_divide_ends_as_on_the_fmus():
    """Stop at 55 ms: the 10 ms components (sensors, EKFs) take their last step at 40 ms (one at
    50 ms would pass the stop time) and hold their outputs, on the batched engine as on the
    FMUs: both follow the one schedule (orchestration/schedule.py)."""
    stop = ["scenario.stop_time=0.055"]
    runs = [stop + [f"scenario.seed={s}"] for s in (1, 2)]
    variables = ["plant.q_a", "ekf_acc.q_a_hat", "ekf_motor.P_x"]
    res = batched.simulate_runs(str(SCENARIO), runs, {v: None for v in variables})
    for r, overrides in enumerate(runs):
        f = study.simulate(str(SCENARIO), overrides, variables)
        assert len(f.time) == 56
        for v in variables:
            assert_array_equal(res[v][r if res[v].shape[0] > 1 else 0], f[v], err_msg=v)
    q = res["ekf_acc.q_a_hat"][0]
    assert np.array_equal(q[41], q[55]) and not np.array_equal(q[40], q[41])   # held after its last step


def test_check_names_seed_quantity_and_difference():
    """A difference above the tolerance stops the study with the seed, the quantity and the number."""
    filters = [study_montecarlo.FilterInfo("ekf_acc", "EkfAccelerometer", True, 10, 0.01, {}, True)]
    rng = np.random.default_rng(1)
    fmu = {"time": np.arange(5.0), "truth": rng.standard_normal((5, 6)),
           "ekf_acc": 1e-5 * rng.standard_normal((5, 6)), "ekf_acc.nees": rng.uniform(1, 9, 5)}
    same = {k: v.copy() for k, v in fmu.items()}
    q = study_montecarlo.checked_quantities
    assert study.check_against_fmus(q(same, filters), q(fmu, filters), "seed 4") == 0.0
    same["ekf_acc"][:, 2:4] *= 1 + 1e-9
    with pytest.raises(study.StudyError, match=r"seed 4: ekf_acc velocity RMSE differs by 1e-09"):
        study.check_against_fmus(q(same, filters), q(fmu, filters), "seed 4")
    with pytest.raises(study.StudyError, match=r"seed 4: the run fails on the FMUs only; rerun with --engine fmu"):
        study.check_against_fmus(q(same, filters), None, "seed 4")


def test_noise_in_the_closed_loop_runs_the_plant_per_run():
    """A controller fed by the noisy encoder puts the noise into the loop: the plant and the
    controller become per-run components (their FMU classes, one instance per run), and the runs
    still equal the FMUs' and differ in their true states."""
    doc = scenario_document(SCENARIO, ["scenario.stop_time=0.05"])
    doc["connections"] = [c.replace("drive_encoder.q_m_meas -> controller.q_m", "encoder.q_m_meas -> controller.q_m")
                          for c in doc["connections"]]
    assert "encoder.q_m_meas -> controller.q_m" in doc["connections"]
    seeds = [1, 2]
    runs = [(f"scenario.seed={s}",) for s in seeds]
    res = batched.simulate_runs(doc, runs, {"plant.q_a": None, "ekf_acc.q_a_hat": None})
    assert res.looped == ["plant", "controller"] and "encoder" in res.batched
    for r, s in enumerate(seeds):
        f = study.simulate(doc, runs[r], ["plant.q_a", "ekf_acc.q_a_hat"])
        assert_array_equal(res["plant.q_a"][r], f["plant.q_a"])
        assert_array_equal(res["ekf_acc.q_a_hat"][r], f["ekf_acc.q_a_hat"])
    assert not np.array_equal(res["plant.q_a"][0], res["plant.q_a"][1])


def test_study_falls_back_to_the_fmus_and_says_why(tmp_path, monkeypatch):
    def refuse(model_identifier):
        raise batched.BatchError(f"no kernel for '{model_identifier}' (test)")
    monkeypatch.setattr(batched, "fmu_class", refuse)
    data = study_montecarlo.run_study(SCENARIO, 2, tmp_path, SHORT, workers=1, progress=False, after=0.1,
                                      plots=False, crlb=False, sweep_runs=0, validation_runs=0)
    assert data["engine"]["used"] == "fmu"
    assert "no kernel for" in data["engine"]["fallback"]


def test_runs_of_another_structure_are_refused():
    with pytest.raises(batched.BatchError, match="run 1 has another structure"):
        batched.simulate_runs(str(SCENARIO), [SHORT, ["scenario.stop_time=0.2"]], {"plant.q_a": None})


@pytest.mark.slow
def test_100_runs_batched_equal_the_fmu_study(tmp_path):
    """The whole Monte Carlo table of 100 runs (seeds 1-100) on both engines: the same numbers."""
    kw = dict(workers=2, progress=False, plots=False, crlb=False, sweep_runs=0, validation_runs=0)
    fast = study_montecarlo.run_study(SCENARIO, 100, tmp_path / "b", engine="batched", check_seeds=5, **kw)
    slow = study_montecarlo.run_study(SCENARIO, 100, tmp_path / "f", engine="fmu", **kw)
    assert fast["engine"]["used"] == "batched" and len(fast["engine"]["checked_seeds"]) == 5
    for name, entry in slow["summary"].items():
        for key, value in entry.items():
            if isinstance(value, float):
                assert fast["summary"][name][key] == value, f"{name} {key}"


def test_particle_filter_stays_on_the_fmus():
    """The particle filter has no kernel: the study's engine refuses it before simulating (the
    study then runs every run through the FMUs)."""
    pf = SCENARIO.with_name("axelsson2012_pf.toml")
    sc, filters, plant = study_montecarlo._scenario_parts(str(pf), SHORT)
    with pytest.raises(batched.BatchError, match="'pf_alg1' .ParticleFilter. differs between runs and has no"):
        study_montecarlo._batched_runs(str(pf), [SHORT + [f"scenario.seed={s}"] for s in (1, 2)], filters,
                                       plant, filters[0].ratio)


def test_a_taped_run_replays_what_it_shared():
    """A tape of one run's shared components, replayed into runs that differ in an estimator's
    parameter, gives bit for bit the runs simulated in full; a component whose parameters differ
    from the tape's is simulated, and so is every consumer of it; a tape of another structure is
    refused."""
    rec = {"plant.q_a": None, "ekf_acc.q_a_hat": None, "ekf_motor.q_a_hat": None}
    own = SHORT + ["scenario.seed=3"]
    taped = batched.simulate_runs(str(SCENARIO), [own], rec, tape=True)
    assert set(taped.tape.reads) == {"plant", "drive_encoder", "controller", "encoder", "imu", "ekf_acc", "ekf_motor"}
    runs = [own + [f"ekf_acc.q_jerk={q}"] for q in (0.5, 2.0)]
    full = batched.simulate_runs(str(SCENARIO), runs, rec)
    replayed = batched.simulate_runs(str(SCENARIO), runs, rec, replay=taped.tape)
    assert replayed.replayed == ["plant", "encoder", "drive_encoder", "controller", "imu", "ekf_motor"]
    for var in rec:
        assert_array_equal(replayed[var], full[var], err_msg=var)
    assert_array_equal(replayed["ekf_motor.q_a_hat"], taped["ekf_motor.q_a_hat"])
    # the encoder differs from the tape: it and the filters it feeds run, the plant is replayed
    noisier = [r + ["encoder.noise=1e-4"] for r in runs]
    partly = batched.simulate_runs(str(SCENARIO), noisier, rec, replay=taped.tape)
    assert partly.replayed == ["plant", "drive_encoder", "controller", "imu"]
    full = batched.simulate_runs(str(SCENARIO), noisier, rec)
    for var in rec:
        assert_array_equal(partly[var], full[var], err_msg=var)
    with pytest.raises(batched.BatchError, match="another structure"):
        batched.simulate_runs(str(SCENARIO), [["scenario.stop_time=0.2"]], rec, replay=taped.tape)
