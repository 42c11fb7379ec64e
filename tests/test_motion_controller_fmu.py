"""The MotionController FMU built and exercised through fmpy."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description
from numpy.testing import assert_allclose

from fmus.robot_plant import motion_control_model as mcm
from fmu_host import Slave
from orchestration.build import validate_fmu

REPO = Path(__file__).resolve().parent.parent
EXAMPLE_CSV = REPO / "orchestration" / "scenarios" / "paths" / "example_waypoints.csv"


@pytest.fixture(scope="session")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["MotionController"]



def test_fmu_validates_and_declares_the_contract(fmu: Path) -> None:
    assert validate_fmu(fmu) == []
    md = read_model_description(str(fmu))
    by_name = {v.name: v for v in md.modelVariables}
    for name in ("q_m", "dp_ref"):
        assert by_name[f"{name}[1]"].causality == "input"
    assert "dq_m[1]" not in by_name            # the drive forms its speed from its encoder
    for name in ("tau_m", "q_a_ref", "dq_a_ref", "ddq_a_ref", "dddq_a_ref", "p_ref", "q_m_ref", "dq_m_hat"):
        assert by_name[f"{name}[2]"].causality == "output"
    assert by_name["velocity_cutoff"].causality == "parameter"
    assert by_name["dddq_a_ref[1]"].unit == "rad/s3"
    assert by_name["path"].type == "String" and by_name["path"].causality == "parameter"
    # direct feedthrough: tau_m on the measurement and the offset; the jerk on nothing
    deps = {o.variable.name: {d.name for d in (o.dependencies or [])} for o in md.outputs}
    assert deps["tau_m[1]"] == {f"{n}[{i}]" for n in ("q_m", "dp_ref") for i in (1, 2)}
    assert deps["dq_m_hat[1]"] == set()       # formed in the step, from the readings before
    assert deps["dddq_a_ref[1]"] == set()
    assert deps["p_ref[2]"] == {"dp_ref[1]", "dp_ref[2]"}


def test_fmu_runs_standalone_under_simulate_fmu(fmu: Path) -> None:
    res = fmpy.simulate_fmu(str(fmu), stop_time=1.0, step_size=1e-3, output_interval=1e-3,
                            start_values={"path": "p1"},
                            output=["p_ref[1]", "p_ref[2]", "dddq_a_ref[1]", "q_a_ref[1]", "tau_m[1]"])
    assert res.shape[0] == 1001
    ref = mcm.build_controller(mcm.MotionControllerParameters(path="p1")).model
    for k in (0, 400, 777, 1000):
        row = ref.sample(float(res["time"][k]))
        assert_allclose([res["p_ref[1]"][k], res["p_ref[2]"][k]], row[mcm.COLUMNS["p_ref"]], atol=1e-12)
        assert_allclose(res["dddq_a_ref[1]"][k], row[mcm.COLUMNS["dddq_a_ref"]][0], atol=1e-9)
        assert_allclose(res["q_a_ref[1]"][k], row[mcm.COLUMNS["q_a_ref"]][0], atol=1e-12)
    assert np.all(np.isfinite(res["tau_m[1]"]))


def test_fmu_matches_the_model_in_a_loop(fmu: Path) -> None:
    """Torque with direct feedthrough from the measurement, the speeds the drive forms from its
    readings in each step, and the integral, as in the model."""
    s = Slave(fmu, {"path": "square"}, instance_name="mc")
    s.fmu.exitInitializationMode()
    ctrl = mcm.build_controller(mcm.MotionControllerParameters(path="square"))
    dt = 1e-3
    rng = np.random.default_rng(1)
    t = 0.0
    for k in range(300):
        row = ctrl.model.sample(t)
        qm = row[mcm.COLUMNS["q_m_ref"]] + rng.normal(0, 1e-3, 2)
        dp = np.array([1e-3, -5e-4]) if k > 150 else np.zeros(2)
        s.set(q_m=qm)
        s.set(dp_ref=dp)
        tau = s.get("tau_m", 2)
        expected = ctrl.evaluate(t, qm, ctrl.law_speed(t), dp)
        assert_allclose(tau, expected, rtol=1e-12, atol=1e-12)
        assert_allclose(s.get("q_a_ref", 2), ctrl.q_a_ref, atol=1e-14)
        assert_allclose(s.get("p_ref", 2), ctrl.p_ref, atol=1e-14)
        s.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=dt)
        ctrl.measure(t + dt, qm)                # the step's output torque is that of t + dt
        ctrl.evaluate(t, qm, ctrl.law_speed(t), dp)
        ctrl.advance(dt)
        assert_allclose(s.get("dq_m_hat", 2), ctrl.velocity, rtol=1e-12, atol=1e-12)
        t = (k + 1) * dt
    assert np.abs(ctrl.velocity).max() > 1.0          # the random readings moved it
    s.close()


def test_fmu_csv_path(fmu: Path) -> None:
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.2, step_size=1e-3,
                            start_values={"path": "csv", "csv_file": str(EXAMPLE_CSV)},
                            output=["p_ref[1]", "p_ref[2]"])
    assert_allclose([res["p_ref[1]"][0], res["p_ref[2]"][0]], [1.2, 0.9], atol=1e-12)


@pytest.mark.parametrize("params, fragment", [
    ({"path": "p7"}, "parameter 'path' = 'p7' is not one of"),
    ({"path": "csv"}, "parameter 'csv_file' must name a waypoint file"),
    ({"path": "csv", "csv_file": "/no/such/file.csv"}, "parameter 'csv_file' = '/no/such/file.csv'"),
    ({"path": "p1", "path_start[1]": 2.5, "path_start[2]": 1.0}, "'path_start' = (2.5, 1.0)"),
    ({"kd[2]": -0.1}, "parameter 'kd[2]'"),
    ({"speed_scale": 0.0}, "parameter 'speed_scale'"),
])
def test_bad_parameters_rejected_naming_the_parameter(fmu: Path, params: dict, fragment: str) -> None:
    s = Slave(fmu, params, instance_name="mc")
    with pytest.raises(Exception):
        s.fmu.exitInitializationMode()
    assert any(fragment in m for m in s.log), s.log
    s.fmu.freeInstance()


def test_a_move_too_slow_to_tabulate_is_named_not_a_memory_error(fmu: Path, tmp_path: Path) -> None:
    """A waypoint speed of 1e-12 m/s: a path of 1e11 s, whose reference table (1.4 PiB) was a
    MemoryError with a traceback; now the parameter and the path's length, before allocating."""
    slow = tmp_path / "slow.csv"
    slow.write_text("x,z,speed,dwell\n1.2,0.9,,0.2\n1.3,0.9,1e-12,0\n")
    s = Slave(fmu, {"path": "csv", "csv_file": str(slow)}, instance_name="mc")
    with pytest.raises(Exception):
        s.fmu.exitInitializationMode()
    assert any(f"parameter 'csv_file' = '{slow}' with 'path_start' = default: path 'csv:slow.csv' "
               "lasts 1e+11 s, longer than the 1200 s the controller tabulates" in m for m in s.log), s.log
    assert not any("MemoryError" in m or "Traceback" in m for m in s.log), s.log
    s.fmu.freeInstance()


def test_bad_csv_row_is_named(fmu: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("x,z,speed\n1.2,0.9,\n1.3,0.9,fast\n")
    s = Slave(fmu, {"path": "csv", "csv_file": str(bad)}, instance_name="mc")
    with pytest.raises(Exception):
        s.fmu.exitInitializationMode()
    assert any(f"{bad}, line 3: column 'speed' is not a number" in m for m in s.log), s.log
    s.fmu.freeInstance()
