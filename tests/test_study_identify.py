"""`flexfusion study identify` (orchestration/study_identify.py) through the FMUs, and the named
parameter sets of scenario files that carry its result (orchestration/scenario.py)."""
from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common.robot_params import RobotParameters
from orchestration import identification as ident
from orchestration import study_identify
from orchestration.cli import main
from orchestration.scenario import ScenarioError, load_scenario, scenario_document
from orchestration.study import simulate
from toys import write

SCENARIO = study_identify.DEFAULT_SCENARIO


#: noise-free, calibrated sensors on the ideal plant (the model's own structure)
NOISE_FREE = ["encoder.noise=0", "encoder.resolution=0", "imu.acc_noise=0", "imu.acc_resolution=0",
              "imu.acc_bias_rw=0", "imu.mount_rpy=[0, 0, 0]", "imu.acc_scale=[0, 0, 0]", "plant.ideal=true"]


# ---- the study, through the FMUs -----------------------------------------------------------
def test_model_simulation_reproduces_the_fmu_experiment(fmu_env):
    """With the plant's own parameters and noise-free sensors, the fit's closed-loop simulation
    (controller, plant timing, accelerometer filter) is the co-simulation to rounding error."""
    overrides = NOISE_FREE + study_identify.experiment_overrides(0, (0.9, -0.6), 0.5) + ["scenario.stop_time=0.6"]
    sc = load_scenario(SCENARIO, overrides)
    run = simulate(SCENARIO, overrides, variables=study_identify.recorded(sc))
    exp = study_identify._experiment("x", sc, run)
    true, _ = study_identify.plant_truth(sc)
    q_m, acc = ident.simulate(true, exp)
    assert np.ptp(exp.q_m, axis=0).min() > 1.0 and np.ptp(exp.acc[:, 0]) > 1.0     # it moved
    assert_allclose(q_m, exp.q_m, atol=1e-9)
    assert_allclose(acc, exp.acc, atol=1e-8)


def test_cli_identifies_the_ideal_plant_and_writes_the_report_and_include(tmp_path, capsys, fmu_env):
    """Noise-free sensors, two short experiments, the study's own starting point (the CAD guess):
    every fitted parameter within 1 % of the plant's, none biased; the include file is a
    parameter set a scenario can use."""
    out, inc = tmp_path / "out", tmp_path / "robot.toml"
    args = ["study", "identify", "--out", str(out), "--include", str(inc), "--working-point", "0.7,1.3",
            "--working-point", "0.9,-0.6", "--stop-time", "0.8", "--workers", "1", "--no-progress"]
    for o in NOISE_FREE:
        args += ["--set", o]
    assert main(args) == 0
    rep = json.loads((out / "identify.json").read_text())
    assert rep["fit"]["converged"] and rep["plant"]["unmodelled_dynamics"] is False
    assert set(rep["parameters"]) == set(ident.NAMES)
    for name, p in rep["parameters"].items():
        assert abs(p["relative_error"]) < 0.01, name
        assert p["biased"] is False and "std" in p and "reason" in p
    assert rep["fixed"]["m1"]["reason"].startswith("fixed at the nominal")
    assert "delta" not in rep["fixed"] and "w_c" not in rep["fixed"]      # fitted, not held at the plant's
    assert set(rep["fixed"]) == set(ident.FIXED) == set(ident.FIXED_REASONS)
    # the study's criterion: the calibration of an ideal accelerometer is estimated as ideal
    assert rep["criterion"] == {"prefilter": 25.0, "prefilter_order": 4, "acc_calibration": True,
                                "initial_state": True}
    cal = rep["acc_calibration"]
    assert abs(cal["scale_x"]) < 1e-4 and abs(cal["scale_z"]) < 1e-4 and max(map(abs, cal["bias"])) < 1e-3
    doc = tomllib.loads(inc.read_text())
    robot = doc["parameter_sets"]["identified_robot"]
    assert_allclose(robot["k_hi"], [rep["parameters"]["k_hi[1]"]["fitted"], rep["parameters"]["k_hi[2]"]["fitted"]])
    assert "flexfusion study identify" in inc.read_text() and "k_lo[1]" in capsys.readouterr().out


def test_non_convergence_is_one_error_and_keeps_the_best_fit(tmp_path, capsys, fmu_env):
    out = tmp_path / "out"
    rc = main(["study", "identify", "--out", str(out), "--working-point", "0.7,1.3", "--stop-time", "0.5",
               "--max-nfev", "1", "--workers", "1", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("error: ") and "did not converge" in err[-1]
    rep = json.loads((out / "identify.json").read_text())
    assert rep["fit"]["converged"] is False and "did not converge" in rep["error"]
    assert set(rep["parameters"]) == set(ident.NAMES)
    assert not (out / "identified_robot.toml").exists()


def test_bad_working_point_is_one_error(tmp_path, capsys):
    assert main(["study", "identify", "--out", str(tmp_path), "--working-point", "0.7"]) == 2
    assert "--working-point '0.7'" in capsys.readouterr().err
    assert main(["study", "identify", "--out", str(tmp_path), "--prefilter", "-1"]) == 2
    assert "--prefilter -1: prefilter cut-off must be a frequency >= 0 Hz" in capsys.readouterr().err


def test_realistic_plant_gives_biased_estimates_and_says_so(tmp_path, fmu_env):
    """Unmodelled dynamics (elastic mode, torque ripple, torque-constant error) bias the fit,
    and identify.json says which estimates and why (a fit that fails to converge on it still
    writes its best fit)."""
    out = tmp_path / "out"
    assert main(["study", "identify", "--out", str(out), "--working-point", "0.7,1.3", "--working-point",
                 "0.9,-0.6", "--stop-time", "0.8", "--workers", "1", "--no-progress",
                 "--set", "plant.ideal=false"]) in (0, 2)
    rep = json.loads((out / "identify.json").read_text())
    assert rep["plant"]["unmodelled_dynamics"] is True
    assert rep["biased"], "a plant with unmodelled dynamics should bias some estimate"
    for name in rep["biased"]:
        assert "dynamics the model lacks" in rep["parameters"][name]["reason"]


# ---- parameter sets (orchestration/scenario.py) ---------------------------------------------
SETS = """
connections = ["src.y -> g.u"]
[scenario]
stop_time = 0.01
base_step = 0.001
include = ["inc.toml"]
[parameter_sets.shared]
slope = 5.0
gain = 2.0
label = "from the set"
[parameter_sets.other]
gain = 4.0
[components.src]
fmu = "Source"
parameter_sets = ["shared"]
[components.g]
fmu = "Gain"
parameter_sets = ["shared", "other"]
[components.g2]
fmu = "Gain"
parameter_sets = ["shared"]
parameters = { gain = 9.0 }
"""


def _params(sc, comp: str) -> dict:
    return {k: v for k, v in sc.components[comp].parameters.items() if k != "seed"}


@pytest.mark.usefixtures("toy_fmus")
def test_parameter_sets_apply_declared_parameters_in_order(tmp_path):
    write(tmp_path, "[parameter_sets.shared]\nslope = 6.0\n", "inc.toml")
    path = write(tmp_path, SETS)
    sc = load_scenario(path)
    assert _params(sc, "src") == {"slope": 6.0, "label": "from the set"}    # included set wins over the file's
    assert _params(sc, "g") == {"gain": 4.0}                                 # a later set wins
    assert _params(sc, "g2") == {"gain": 9.0}                                # own parameters win
    sc = load_scenario(path, ["g2.gain=1", "parameter_sets.shared.label=cli", "g.parameter_sets=[]"])
    assert _params(sc, "g2") == {"gain": 1.0} and _params(sc, "src")["label"] == "cli"
    assert _params(sc, "g") == {}
    sc = load_scenario(path, ["parameter_sets.shared={}"])
    assert _params(sc, "src") == {} and _params(sc, "g") == {"gain": 4.0}
    # the merged document (what studies pass around) keeps the sets
    assert {n: c.parameters for n, c in load_scenario(scenario_document(path)).components.items()} == \
        {n: c.parameters for n, c in load_scenario(path).components.items()}


@pytest.mark.usefixtures("toy_fmus")
@pytest.mark.parametrize("change, message", [
    (('parameter_sets = ["shared"]\n[components.g]', 'parameter_sets = ["nope"]\n[components.g]'),
     r"s\.toml: component 'src': unknown parameter set 'nope' \(defined: shared, other\)"),
    (('parameter_sets = ["shared"]\n[components.g]', 'parameter_sets = "shared"\n[components.g]'),
     r"component 'src': 'parameter_sets' must be a list of set names"),
    (("slope = 5.0", 'slope = "steep"'), r"component 'src': parameter set 'shared': parameter 'slope' is Real"),
    (("gain = 4.0", "gain = [4.0, 1.0]"), r"component 'g': parameter set 'other': parameter 'gain' is a scalar"),
    (("gain = 4.0", "gain = 4.0\ntypo = 1.0"), r"parameter set 'other': 'typo' is a parameter of none of the "
                                               r"components that use the set \(g\)"),
    (("[parameter_sets.other]\ngain = 4.0", "[parameter_sets]\nother = 3"),
     r"\[parameter_sets\.other\] must be a table"),
])
def test_parameter_set_errors_name_file_component_and_set(tmp_path, change, message):
    write(tmp_path, "", "inc.toml")
    path = write(tmp_path, SETS.replace(*change))
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)


@pytest.mark.usefixtures("toy_fmus")
def test_parameter_set_errors_in_includes_and_overrides(tmp_path):
    write(tmp_path, "[parameter_sets]\nshared = 1\n", "inc.toml")
    path = write(tmp_path, SETS)
    with pytest.raises(ScenarioError, match=r"inc\.toml: \[parameter_sets\.shared\] must be a table"):
        load_scenario(path)
    write(tmp_path, "[other]\nx = 1\n", "inc.toml")
    with pytest.raises(ScenarioError, match=r"inc\.toml: unknown key\(s\) other"):
        load_scenario(path)
    write(tmp_path, "", "inc.toml")
    with pytest.raises(ScenarioError, match=r"unknown parameter set 'nope'"):
        load_scenario(path, ["parameter_sets.nope.gain=1"])


def test_report_says_which_estimates_are_biased_and_why():
    """An error beyond 3 std is biased; on a plant marked non-ideal the reason names the
    unmodelled dynamics; an undetermined parameter (infinite std) is said to be so."""
    true = RobotParameters()
    values = dict(zip(ident.NAMES, ident.parameter_values(true)))
    std = {n: 1e-3 * v for n, v in values.items()}
    values["k_lo[1]"] *= 1.01                                   # 10 std off
    values["d[2]"] *= 1.0015                                    # 1.5 std off: not biased, covered
    std["f_v[1]"] = float("inf")
    fit = ident.Fit(ident.robot_from_values(list(values.values()), true), values, std, 1.0, 1.0, 100, 3, True, "")
    rep = study_identify.report(fit, true, ideal=False)
    assert rep["biased"] == ["k_lo[1]"] and rep["plant"]["unmodelled_dynamics"] is True
    assert "dynamics the model lacks" in rep["parameters"]["k_lo[1]"]["reason"]
    # the error in std of log(value) (the fit runs in log space): log(1.01) / (1e-3 / 1.01)
    assert_allclose(rep["parameters"]["k_lo[1]"]["error_in_std"], np.log(1.01) * 1.01e3, rtol=1e-12)
    assert rep["parameters"]["k_lo[1]"]["covers_true"] is False and rep["parameters"]["d[2]"]["covers_true"] is True
    lo, hi = rep["parameters"]["d[2]"]["interval95"]
    assert_allclose(np.log(hi / lo) / 2, 1.959963984540054 * 1e-3 / 1.0015, rtol=1e-12)
    assert rep["uncertainty"]["coverage"]["true"]["not_covered"] == ["k_lo[1]"]
    assert rep["uncertainty"]["coverage"]["true"]["of"] == len(ident.NAMES) - 1
    assert rep["parameters"]["d[2]"]["biased"] is False
    assert rep["parameters"]["f_v[1]"]["std"] is None and "not determined" in rep["parameters"]["f_v[1]"]["reason"]
    json.dumps(rep)                                              # JSON-able (no inf, no numpy types)
    rep = study_identify.report(fit, true, ideal=None)
    assert rep["plant"]["unmodelled_dynamics"] is False and "insufficient" in rep["parameters"]["k_lo[1]"]["reason"]


def test_report_gives_effective_values_their_coverage_and_bounded_estimates_their_range(tmp_path):
    """``--effective``: the effective values (a noise-free fit's identify.json) beside the true
    ones, with whether each 95 % interval covers them; an estimate on the bound of its stated
    range is not determined: its interval is the range."""
    true = RobotParameters()
    values = dict(zip(ident.NAMES, ident.parameter_values(true)))
    std = {n: 1e-3 * v for n, v in values.items()}
    values["k_hi[1]"] *= 0.9                                     # biased against the truth ...
    values["w_c[1]"] = ident.RANGES["w_c"][0]                    # ... on its bound
    bound = {n: (ident.RANGES["w_c"] if n == "w_c[1]" else None) for n in ident.NAMES}
    fit = ident.Fit(ident.robot_from_values(list(values.values()), true), values, std, 1.0, 1.0, 100, 3, True, "",
                    at_bound=bound)
    eff_file = tmp_path / "identify.json"
    eff = {n: {"fitted": v * (1.0005 if n == "k_hi[1]" else 1.0)} for n, v in values.items()}
    eff_file.write_text(json.dumps({"parameters": eff, "experiments": {"duration": 4.8}, "fit": {"converged": True}}))
    rep = study_identify.report(fit, true, ideal=False, effective=study_identify.load_effective(eff_file))
    k = rep["parameters"]["k_hi[1]"]
    assert k["covers_true"] is False and k["covers_effective"] is True
    assert_allclose(k["effective"], values["k_hi[1]"] * 1.0005)
    w = rep["parameters"]["w_c[1]"]
    assert w["at_bound"] and w["interval95"] == list(ident.RANGES["w_c"]) and "stated range" in w["reason"]
    assert w["covers_true"] is True and w["biased"] is False
    cov = rep["uncertainty"]["coverage"]
    assert cov["effective"]["covered"] == 20 and cov["true"]["not_covered"] == ["k_hi[1]"]
    assert rep["effective"]["experiments"] == {"duration": 4.8}
    json.dumps(rep)


def test_bad_effective_file_is_one_error(tmp_path, capsys):
    missing = tmp_path / "none.json"
    assert main(["study", "identify", "--out", str(tmp_path), "--effective", str(missing)]) == 2
    assert f"--effective {missing}: no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"parameters": {}}')
    assert main(["study", "identify", "--out", str(tmp_path), "--effective", str(bad)]) == 2
    assert "not an identify.json with every fitted parameter" in capsys.readouterr().err
    assert main(["study", "identify", "--out", str(tmp_path), "--effective", str(bad), "--noise-free"]) == 2
    assert "give one" in capsys.readouterr().err
