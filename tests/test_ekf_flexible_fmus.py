"""The EkfComplete, EkfMotor and EkfIntegrated FMUs (Henriksson et al. 2009, section III-A) built,
validated and exercised through fmpy against the plain model."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description
from numpy.testing import assert_allclose

from fmus.common import dynamics
from fmus.common.parameters import replace
from fmus.estimators import ekf_flexible_model as em
from fmu_host import Slave
import ekf_flexible_truth as truth

NAMES = {"complete": "EkfComplete", "motor": "EkfMotor", "integrated": "EkfIntegrated"}
T = truth.T


@pytest.fixture(scope="session")
def fmus(every_fmu: dict[str, Path]) -> dict[str, Path]:
    return {v: every_fmu[n] for v, n in NAMES.items()}


@pytest.mark.parametrize("variant", em.VARIANTS)
def test_model_description(fmus: dict, variant: str) -> None:
    md = read_model_description(str(fmus[variant]), validate=True)
    assert md.coSimulation.modelIdentifier == NAMES[variant]
    v = {x.name: x for x in md.modelVariables}
    expected = [("tau_m[2]", "N.m"), ("q_m_meas[1]", "rad"), ("q_a_hat[2]", "rad"), ("dq_a_hat[1]", "rad/s"),
                ("ddq_a_hat[2]", "rad/s2"),
                ("q_m_hat[1]", "rad"), ("p_tool_hat[2]", "m"), ("trace_P_p", "m2"), ("innovation_norm", "1")]
    if variant != "motor":
        expected += [("acc_s[3]", "m/s2"), ("stiffness_factor_hat", "1")]
    if variant == "integrated":
        expected.append(("v_acc[2]", "m/s"))
        assert v["drift_correction"].causality == "parameter"
    for name, unit in expected:
        assert v[name].unit == unit, name
    assert ("acc_s[1]" in v) == (variant != "motor")
    for name in ("lambda1", "lambda5", "stiffness_scale", "k_hi[1]", "k_lo[2]", "w_dq_a", "r_motor",
                 "q_a0[1]", "p_tool0[2]"):
        assert v[name].causality == "parameter", name
    # the filtered estimate feeds through from the measurements and their time stamp, not from
    # the torque
    deps = {o.variable.name: {d.name for d in o.dependencies} for o in md.outputs}
    meas = {"q_m_meas[1]", "q_m_meas[2]", "t_meas"}
    if variant != "motor":
        meas |= {"acc_s[1]", "acc_s[2]", "acc_s[3]"}
    assert deps["p_tool_hat[1]"] == meas


@pytest.mark.parametrize("variant,start", [(v, {}) for v in em.VARIANTS]
                         + [("integrated", {"drift_correction": "tilt_stiffness", "substeps": 2})])
def test_runs_standalone_under_simulate_fmu(fmus: dict, variant: str, start: dict) -> None:
    """Default inputs (motors at zero, no torque, the accelerometer at rest): the model falls
    under gravity and the zero motor angles pull it back; nothing may blow up in 0.1 s."""
    res = fmpy.simulate_fmu(str(fmus[variant]), stop_time=0.1, step_size=T, output_interval=T,
                            start_values=start)
    assert len(res) >= 200
    for name in res.dtype.names:
        assert np.all(np.isfinite(res[name])), name
    assert np.all(res["trace_P_p"] > 0)


@pytest.mark.parametrize("variant,correction", [(v, "off") for v in em.VARIANTS]
                         + [("integrated", "tilt_stiffness"), ("complete", "stiffness")])
def test_fmu_matches_the_plain_model(fmus: dict, variant: str, correction: str) -> None:
    d = truth.simulate()
    n = 400                                               # 0.2 s, through the first hammer strike
    k0 = int(0.2 / T)                                     # at rest: the static alignment holds
    params = dict(q_a0=d["q_a0"], lambda3=3.0, stiffness_scale=0.8)
    if variant == "integrated":
        params["drift_correction"] = correction
    elif correction == "stiffness":
        params["estimate_stiffness"] = True
    ekf = em.make_filter(variant, **params)
    s = Slave(fmus[variant], params)
    s.init()
    for j in range(n):
        k = k0 + j
        inputs = dict(tau_m=d["tau"][k], q_m_meas=d["q_m"][k])
        if variant != "motor":
            inputs["acc_s"] = d["acc_s"][k]
        s.set(**inputs)
        xf = ekf.update(d["q_m"][k], d["acc_s"][k], d["tau"][k])
        assert_allclose(s.get("q_a_hat", 2), xf[0:2], rtol=1e-12, atol=1e-15)
        assert_allclose(s.get("dq_a_hat", 2), xf[4:6], rtol=1e-12, atol=1e-14)
        assert_allclose(s.get("q_m_hat", 2), xf[2:4], rtol=1e-12, atol=1e-13)
        sig = ekf.stiffness_factor(xf)          # the model's springs times the estimated factor
        robot = replace(ekf.robot, k_lo=tuple(sig * k for k in ekf.robot.k_lo),
                        k_hi=tuple(sig * k for k in ekf.robot.k_hi))
        ddq = dynamics.arm_acceleration(xf[0:8], (0.0, 0.0), robot)
        assert_allclose(s.get("ddq_a_hat", 2), ddq, rtol=1e-12, atol=1e-12)
        assert_allclose(s.get("p_tool_hat", 2), ekf.tool_position(xf), rtol=1e-12)
        assert_allclose(s.get("trace_P_p"), ekf.tool_position_variance(), rtol=1e-10)
        assert_allclose(s.get("innovation_norm"), ekf.innovation_norm, rtol=1e-9)
        if variant == "integrated":
            assert_allclose(s.get("v_acc", 2), ekf.v_int, rtol=1e-12, atol=1e-15)
        if variant != "motor":
            assert_allclose(s.get("stiffness_factor_hat"), sig, rtol=1e-12)
        ekf.predict(T)
        s.step(T)
    s.close()
    if correction != "off":
        assert ekf.stiffness_factor() > 1.05        # the model's 0.8 is being corrected upwards


def test_gauss_seidel_inputs_are_fused_after_the_prediction(fmus: dict) -> None:
    """A master that sets the measurements of t + T (and the torque of t + T) before doStep(t, T)
    and reads after it: the FMU predicts with the torque of t, then fuses the new samples."""
    d = truth.simulate()
    n = 100
    ekf = em.make_filter("complete", q_a0=d["q_a0"])
    s = Slave(fmus["complete"], dict(q_a0=d["q_a0"]))
    s.set(tau_m=d["tau"][0], q_m_meas=d["q_m"][0], acc_s=d["acc_s"][0])
    s.init()
    ekf.update(d["q_m"][0], d["acc_s"][0], d["tau"][0])
    for k in range(1, n):
        s.set(tau_m=d["tau"][k], q_m_meas=d["q_m"][k], acc_s=d["acc_s"][k])
        s.step(T)
        ekf.predict(T)
        xf = ekf.update(d["q_m"][k], d["acc_s"][k], d["tau"][k])
        assert_allclose(s.get("q_a_hat", 2), xf[0:2], rtol=1e-12, atol=1e-15)
    s.close()


@pytest.mark.parametrize("variant", em.VARIANTS)
def test_divergence_is_an_fmi_error_not_nan(fmus: dict, variant: str) -> None:
    s = Slave(fmus[variant])
    s.init()
    s.step(T)
    s.set(q_m_meas=(1e250, -1e250), tau_m=(1e250, 1e250))   # absurd (finite) readings
    with pytest.raises(Exception):
        for _ in range(5):
            s.step(T)
    assert any("EKF diverged" in line for line in s.log), s.log
    n_log = len(s.log)
    with pytest.raises(Exception):        # and it stays stopped, saying why
        s.step(T)
    assert len(s.log) > n_log and "EKF diverged" in s.log[-1]
    for name in ("q_a_hat", "dq_a_hat", "ddq_a_hat", "q_m_hat", "p_tool_hat"):
        assert np.all(np.isfinite(s.get(name, 2))), name
    assert np.isfinite(s.get("trace_P_p")) and np.isfinite(s.get("innovation_norm"))


def test_many_instances_in_one_process(fmus: dict) -> None:
    """pythonfmu 0.7 drops a reference to the script's module dictionary per instance (see
    EkfFlexibleSlave.__init_subclass__ in ekf_flexible_fmu_base): without the balance the second instance fails."""
    for _ in range(8):
        s = Slave(fmus["motor"], dict(q_a0=(0.1, 0.1)))
        s.init()
        s.step(T)
        assert np.all(np.isfinite(s.get("q_a_hat", 2)))
        s.close()


def test_bad_parameter_is_named(fmus: dict) -> None:
    bad = Slave(fmus["integrated"], dict(lambda2=-1.0))
    with pytest.raises(Exception):
        bad.init()
    assert any("lambda2" in line for line in bad.log), bad.log
