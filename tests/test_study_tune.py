"""study_tune: the generic tuner (differential evolution over scenario runs) on a toy case, the
scenario pruning, the include file, and the CLI's argument handling."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from orchestration import study_tune as st
from orchestration.scenario import load_scenario
from orchestration.study import StudyError, open_executor

pytestmark = pytest.mark.usefixtures("toy_fmus")

# truth src.ys = (t, 2t); estimate g.yv = gain * src.ys: the error is smallest at gain = 1
TOY = """
connections = ["src.ys -> g.uv", "src.y -> other.u"]
[scenario]
name = "toy_tune"
stop_time = 0.1
base_step = 0.01
[components.src]
fmu = "Source"
[components.g]
fmu = "Gain"
parameters = { gain = 3.0 }
[components.other]
fmu = "Gain"
[record]
variables = ["src.ys", "g.yv", "other.y"]
"""


def _toy(tmp_path: Path) -> Path:
    p = tmp_path / "toy.toml"
    p.write_text(TOY)
    return p


def test_prune_keeps_what_the_estimate_needs(fmu_env, tmp_path) -> None:
    doc = st.load_document(_toy(tmp_path))
    small = st.prune(doc, ["g.yv", "src.ys"])
    assert set(small["components"]) == {"src", "g"}
    assert small["connections"] == ["src.ys -> g.uv"]
    assert small["record"]["variables"] == ["g.yv", "src.ys"]
    p1 = st.load_document(Path(st.__file__).parent / "scenarios" / "henriksson2009_p1.toml")
    small = st.prune(p1, ["observer.p_tool_hat", "plant.p_tool"])
    assert set(small["components"]) == {"controller", "plant", "pulses", "encoder", "imu", "observer"}
    bounds = st.default_bounds(p1, "observer")
    # the ranges the observer FMU declares (its vendor annotation), pole pairs of section III-C-2
    assert bounds == {**{f"pole_freq[{i}]": (0.3, 60.0) for i in range(1, 5)},
                      **{f"pole_damping[{i}]": (0.2, 3.0) for i in range(1, 5)}}
    assert list(bounds) == [*(f"pole_freq[{i}]" for i in range(1, 5)), *(f"pole_damping[{i}]" for i in range(1, 5))]
    with pytest.raises(StudyError, match="no default tuning parameters"):
        st.default_bounds(p1, "plant")


def test_tune_finds_the_optimum_of_a_toy(tmp_path) -> None:
    res = st.tune(_toy(tmp_path), "g", {"gain": (0.1, 10.0)}, truth="src.ys", estimate="g.yv",
                  after=0.0, maxiter=8, popsize=5, seed=1, progress=False)
    assert res.params["gain"] == pytest.approx(1.0, abs=0.02)
    # cost = rmse of (gain - 1) (t, 2 t) over the record, evaluated independently
    t = np.arange(0.0, 0.1 + 1e-9, 0.01)
    assert_allclose(res.cost, abs(res.params["gain"] - 1) * np.sqrt(np.mean(5 * t * t)), rtol=1e-6)
    assert res.n_evals == len(res.history) <= 5 * (8 + 1)
    assert min(h["cost"] for h in res.history) == pytest.approx(res.cost)
    assert res.failed == 0 and res.wall_time > 0


def test_tune_reports_convergence_or_the_budget_running_out(tmp_path) -> None:
    """A loose tolerance (0.5: the population's cost spread within half its mean) is met on the
    toy within its budget, and the result says so and in how many generations; an unreachable
    one (1e-12) with one generation says the budget ran out, also in the include's comment,
    which names --tol."""
    conv = st.tune(_toy(tmp_path), "g", {"gain": (0.1, 10.0)}, truth="src.ys", estimate="g.yv",
                   after=0.0, maxiter=30, popsize=5, seed=1, tol=0.5, progress=False)
    assert conv.converged and 1 <= conv.generations < 30 and conv.tol == 0.5 and conv.maxiter == 30
    assert st.convergence(conv) == f"converged (tol 0.5) in {conv.generations} of 30 generations"
    assert conv.to_json()["converged"] is True
    from orchestration.cli import main
    assert main(["study", "tune", str(_toy(tmp_path)), "--estimator", "g", "--truth", "src.ys", "--estimate", "g.yv",
                 "--param", "gain=0.1:10", "--after", "0", "--maxiter", "1", "--popsize", "3", "--tol", "1e-12",
                 "--workers", "1", "--no-progress", "--engine", "fmu", "--out", str(tmp_path / "o")]) == 0
    text = (tmp_path / "o" / "tuned_g.toml").read_text()
    assert "--tol 1e-12" in text and "NOT converged: the budget of 1 generations ran out" in text
    assert json.loads((tmp_path / "o" / "tune_g.json").read_text())["converged"] is False


def test_tune_on_the_study_executor_and_include(tmp_path) -> None:
    """The population runs in worker processes (workers=executor.map); the include file
    sets the tuned value in a scenario."""
    with open_executor(workers=2) as ex:
        res = st.tune(_toy(tmp_path), "g", {"gain": (0.1, 10.0), "offset": (-1.0, 1.0)}, truth="src.ys",
                      estimate="g.yv", after=0.0, maxiter=1, popsize=3, seed=0, executor=ex,
                      progress=False)
    assert res.n_evals == 6 * 2
    assert set(res.params) == {"gain", "offset"}
    inc = st.write_include(tmp_path / "tuned.toml", "g", {**res.params, "v[1]": 1.0, "v[2]": 2.0},
                           comment="test")
    text = inc.read_text()
    assert "v = [1.0, 2.0]" in text and text.startswith("# test")
    scen = tmp_path / "with_include.toml"
    scen.write_text(TOY.replace('name = "toy_tune"', 'name = "toy_tune"\ninclude = ["tuned_g.toml"]'))
    st.write_include(tmp_path / "tuned_g.toml", ["g", "other"], res.params)
    sc = load_scenario(scen)
    assert sc.components["g"].parameters["gain"] == pytest.approx(res.params["gain"])
    assert sc.components["other"].parameters["offset"] == pytest.approx(res.params["offset"])


def test_a_failing_candidate_costs_the_penalty_and_bad_bounds_are_refused(tmp_path) -> None:
    doc = st.prune(st.load_document(_toy(tmp_path)), ["g.yv", "src.ys"])
    assert st.evaluate(doc, ["g.no_such_param=1"], "g.yv", "src.ys", 0.0, "rmse") == st.PENALTY
    with pytest.raises(StudyError, match="low < high"):
        st.tune(_toy(tmp_path), "g", {"gain": (2.0, 1.0)}, truth="src.ys", estimate="g.yv", progress=False)
    with pytest.raises(StudyError, match="not in the scenario"):
        st.tune(_toy(tmp_path), "nope", {"gain": (0.5, 2.0)}, progress=False)
    from orchestration.scenario import ScenarioError
    with pytest.raises(ScenarioError, match="no_such_param"):
        st.tune(_toy(tmp_path), "g", {"no_such_param": (0.5, 2.0)}, truth="src.ys", estimate="g.yv",
                progress=False)
    with pytest.raises(StudyError, match="NAME=LOW:HIGH"):
        st.parse_param("gain=1")
    assert st.parse_param("pole_freq[2]=0.5:40") == ("pole_freq[2]", (0.5, 40.0))


def test_sensor_floors_bound_the_ekf_measurement_noise(fmu_env) -> None:
    """Encoder: sqrt(noise^2 + step^2 / 12) (white noise plus uniform rounding error), and
    lambda5's low bound puts sqrt(lambda5) * r_motor exactly there; a noisier encoder raises it."""
    from fmus.robot_plant.sensor_model import EncoderParameters
    from fmus.robot_plant.sensor_model import ImuParameters
    p1 = st.load_document(Path(st.__file__).parent / "scenarios" / "henriksson2009_p1.toml")
    enc, imu = EncoderParameters(), ImuParameters()
    floors = st.sensor_floors(p1)
    assert_allclose(floors["encoder"], np.hypot(enc.noise, enc.resolution / np.sqrt(12)), rtol=1e-12)
    assert_allclose(floors["accelerometer"], np.hypot(imu.acc_noise, imu.acc_resolution / np.sqrt(12)),
                    rtol=1e-12)
    # the rounding error of a uniform step is Delta^2 / 12: check the formula on samples
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, 200_000)
    noisy = x + enc.noise * rng.standard_normal(x.size)
    err = np.round(noisy / enc.resolution) * enc.resolution - x
    assert_allclose(err.std(), floors["encoder"], rtol=0.01)
    for comp in ("ekf_complete", "ekf_motor", "ekf_integrated", "ekf_integrated_fixed"):
        lo, hi = st.default_bounds(p1, comp)["lambda5"]
        r_motor = st.parameter_value(p1, comp, "r_motor", 1e-4)
        assert_allclose(np.sqrt(lo) * r_motor, floors["encoder"], rtol=1e-12)
        assert hi > lo
    p1["components"]["encoder"].setdefault("parameters", {})["noise"] = 1e-4
    assert st.sensor_floors(p1)["encoder"] > floors["encoder"]
    assert st.default_bounds(p1, "ekf_motor")["lambda5"][0] > 1.0


def test_shipped_tuning_respects_the_sensor_floors() -> None:
    """Every tuned EKF of the 2009 scenarios claims at least the encoder's physical error, and
    EKF Complete's (untuned) accelerometer std at least the Imu's."""
    p1 = st.load_document(Path(st.__file__).parent / "scenarios" / "henriksson2009_p1.toml")
    floors = st.sensor_floors(p1)
    ekfs = [c for c in p1["components"] if st.fmu_type(p1, c).startswith("Ekf")]
    assert len(ekfs) == 4
    for comp in ekfs:
        lam5 = st.parameter_value(p1, comp, "lambda5", 1.0)
        assert np.sqrt(lam5) * st.parameter_value(p1, comp, "r_motor", 1e-4) >= floors["encoder"] * (1 - 1e-9), comp
    assert st.parameter_value(p1, "ekf_complete", "r_acc", 0.05) >= floors["accelerometer"]


def test_held_out_seeds(tmp_path) -> None:
    """Training and held-out costs are reported; the scenario's own value (gain 3) is evaluated
    too; overlapping seeds are refused."""
    res = st.tune(_toy(tmp_path), "g", {"gain": (0.1, 10.0)}, truth="src.ys", estimate="g.yv",
                  after=0.0, maxiter=4, popsize=5, seed=1, progress=False, seeds=[1, 2], holdout_seeds=[3])
    t = np.arange(0.0, 0.1 + 1e-9, 0.01)
    rms = np.sqrt(np.mean(5 * t * t))
    assert res.seeds == [1, 2] and res.holdout_seeds == [3]
    assert_allclose(res.initial_cost, 2.0 * rms, rtol=1e-6)          # gain 3: error 2 (t, 2t)
    assert_allclose(res.initial_holdout_cost, 2.0 * rms, rtol=1e-6)
    assert_allclose(res.holdout_cost, abs(res.params["gain"] - 1) * rms, rtol=1e-6)   # the toy has no noise
    assert res.to_json()["holdout_cost"] == res.holdout_cost
    with pytest.raises(StudyError, match="also training seeds"):
        st.tune(_toy(tmp_path), "g", {"gain": (0.1, 10.0)}, truth="src.ys", estimate="g.yv",
                progress=False, seeds=[1, 2], holdout_seeds=[2, 3])
    assert st.parse_seeds("1, 2") == [1, 2] and st.parse_seeds(None) == []
    with pytest.raises(StudyError, match="integers"):
        st.parse_seeds("a,b")


def test_the_cli_forms(tmp_path, capsys) -> None:
    """``flexfusion study tune`` as before (explicit estimate and truth, --param, the study
    executor) and with ``--engine fmu``: the toys are not this project's FMUs, so the default
    batched engine says in one line that it runs them through the FMUs; an unknown engine is
    refused."""
    import json

    from orchestration.cli import main
    args = ["study", "tune", str(_toy(tmp_path)), "--estimator", "g", "--truth", "src.ys", "--estimate", "g.yv",
            "--param", "gain=0.1:10", "--after", "0", "--maxiter", "1", "--popsize", "3", "--workers", "1",
            "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert "tune g: the batched engine cannot run this tuning" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "b"), "--engine", "fmu"]) == 0
    assert "batched engine" not in capsys.readouterr().err
    a, b = (json.loads((tmp_path / d / "tune_g.json").read_text()) for d in ("a", "b"))
    assert a["engine"]["used"] == b["engine"]["used"] == "fmu" and "fallback" not in b["engine"]
    assert a["params"] == b["params"] and (tmp_path / "a" / "tuned_g.toml").exists()
    with pytest.raises(SystemExit):
        main(args + ["--out", str(tmp_path / "c"), "--engine", "gpu"])
