"""The EkfAccelerometer FMU built, validated and exercised through fmpy, against the plain model."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description
from numpy.testing import assert_allclose

from fmus.common import kinematics
from fmus.common.frames import G
from fmus.estimators import axelsson2012_model as am
from fmus.estimators import ekf_accelerometer_model as em
from fmu_host import Slave

T = 0.01


@pytest.fixture(scope="session")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["EkfAccelerometer"]



def _signals(n: int, p: am.EkfAccelerometerParameters, seed: int = 0):
    """A smooth arm motion, its noisy motor angles and accelerometer readings (eqs. 15-19) and
    its jerk, the inputs of the filter; accelerometer as 3-vectors with x at ``index_x`` and z
    at ``index_z``."""
    t = np.arange(n) * T
    q0, A, w = np.array([0.2, -0.1]), np.array([0.05, 0.03]), np.array([3.0, 5.0])
    x = np.column_stack([q0 + A * np.sin(np.outer(t, w)), A * w * np.cos(np.outer(t, w)),
                         -A * w ** 2 * np.sin(np.outer(t, w))])
    u = -A * w ** 3 * np.cos(np.outer(t, w))
    mm = am.MeasurementModel(p.robot(), am.Layout(True, False))
    rng = np.random.default_rng(seed)
    qm = np.array([mm.motor_angles(xk) for xk in x]) + rng.normal(0, 1e-3, (n, 2))
    f = np.array([mm.specific_force(xk) for xk in x]) + rng.normal(0, 1e-2, (n, 2))
    acc = np.full((n, 3), 0.123)     # the unused (y) axis holds something
    acc[:, p.index_x - 1], acc[:, p.index_z - 1] = f[:, 0], f[:, 1]
    return qm, acc, f, u, x


def test_model_description(fmu: Path) -> None:
    md = read_model_description(str(fmu), validate=True)
    assert md.coSimulation.modelIdentifier == "EkfAccelerometer"
    v = {x.name: x for x in md.modelVariables}
    for name, unit in (("q_m_meas[1]", "rad"), ("acc_s[3]", "m/s2"), ("dddq_a_ref[2]", "rad/s3"),
                       ("q_a_hat[1]", "rad"), ("dq_a_hat[2]", "rad/s"), ("ddq_a_hat[1]", "rad/s2"),
                       ("p_tool_hat[2]", "m"), ("trace_P_q", "rad2"), ("innovation_norm", "1")):
        assert v[name].unit == unit, name
    for name in ("use_accelerometer", "use_bias", "q_jerk", "r_motor", "r_acc", "gear_ratio[1]", "k_hi[2]",
                 "q_a0[1]", "p_tool0[2]", "index_x"):
        assert v[name].causality == "parameter", name
    # the filtered estimate feeds through from the measurements and their time stamp, not from
    # the jerk input
    deps = {o.variable.name: {d.name for d in o.dependencies} for o in md.outputs}
    assert deps["q_a_hat[1]"] == {"q_m_meas[1]", "q_m_meas[2]", "acc_s[1]", "acc_s[2]", "acc_s[3]",
                                  "t_meas"}


def test_runs_standalone_under_simulate_fmu(fmu: Path) -> None:
    res = fmpy.simulate_fmu(str(fmu), stop_time=1.0, step_size=T, output_interval=T)
    assert len(res) >= 100
    for name in res.dtype.names:
        assert np.all(np.isfinite(res[name])), name
    assert np.all(res["trace_P_q"] > 0)
    # default inputs: motors at zero, the accelerometer at rest at the home pose: the estimate
    # stays near the home pose (within the gravity deflection of the gearboxes)
    assert np.abs(res["q_a_hat[1]"]).max() < 5e-3 and np.abs(res["q_a_hat[2]"]).max() < 5e-3


@pytest.mark.parametrize("params", [
    dict(),
    dict(use_accelerometer=False),
    dict(use_bias=True, index_x=3, index_z=1, q_jerk=3.0, r_acc=4e-4),
], ids=["paper", "motor-only", "bias-swapped-axes"])
def test_fmu_matches_the_plain_model(fmu: Path, params: dict) -> None:
    n = 60
    p = am.EkfAccelerometerParameters(q_a0=(0.2, -0.1), **params)
    qm, acc, f, u, x = _signals(n, p)
    s = Slave(fmu, dict(q_a0=(0.2, -0.1), **params))
    s.init()
    ekf = em.EkfAccelerometerModel(p)
    for k in range(n):
        s.set(q_m_meas=qm[k], acc_s=acc[k], dddq_a_ref=u[k])
        xf = ekf.update(ekf.measurement_vector(qm[k], f[k]))
        assert_allclose(s.get("q_a_hat", 2), xf[0:2], rtol=1e-12, atol=1e-15)
        assert_allclose(s.get("dq_a_hat", 2), xf[2:4], rtol=1e-12, atol=1e-14)
        assert_allclose(s.get("ddq_a_hat", 2), xf[4:6], rtol=1e-12, atol=1e-13)
        assert_allclose(s.get("p_tool_hat", 2), kinematics.tool_position(xf[0:2], p), rtol=1e-12)
        assert_allclose(s.get("trace_P_q"), ekf.P[0, 0] + ekf.P[1, 1], rtol=1e-12)
        assert_allclose(s.get("innovation_norm"), ekf.innovation_norm, rtol=1e-10)
        ekf.predict(0.5 * ((u[k - 1] if k else 0.0) + u[k]), T)   # mean of the last two jerk inputs
        s.step(T)
    s.close()
    # and it estimates the motion (the filtered estimate at the last sample)
    assert np.abs(xf[0:2] - x[-1, 0:2]).max() < 2e-4


def test_gauss_seidel_inputs_are_fused_after_the_prediction(fmu: Path) -> None:
    """Our master sets the measurements of t + T before doStep(t, T) and reads after it: the FMU
    must predict to t + T first and then fuse them (else the estimate runs one step ahead)."""
    n = 40
    p = am.EkfAccelerometerParameters(q_a0=(0.2, -0.1))
    qm, acc, f, u, x = _signals(n, p)
    s = Slave(fmu, dict(q_a0=(0.2, -0.1)))
    s.set(q_m_meas=qm[0], acc_s=acc[0], dddq_a_ref=u[0])
    s.init()
    ekf = em.EkfAccelerometerModel(p)
    ekf.update(ekf.measurement_vector(qm[0], f[0]))
    for k in range(n - 1):
        s.set(q_m_meas=qm[k + 1], acc_s=acc[k + 1], dddq_a_ref=u[k + 1])
        s.step(T)
        ekf.predict(0.5 * (u[k] + u[k + 1]), T)
        xf = ekf.update(ekf.measurement_vector(qm[k + 1], f[k + 1]))
        assert_allclose(s.get("q_a_hat", 2), xf[0:2], rtol=1e-12, atol=1e-15)
        assert_allclose(s.get("dq_a_hat", 2), xf[2:4], rtol=1e-12, atol=1e-14)
    s.close()


def test_divergence_is_an_fmi_error_not_nan(fmu: Path) -> None:
    s = Slave(fmu)
    s.init()
    s.set(q_m_meas=(0.0, 0.0), acc_s=(0.0, 0.0, G))
    s.step(T)
    s.set(acc_s=(1e200, 0.0, G))      # an absurd (finite) reading throws the filter out
    with pytest.raises(Exception):
        for _ in range(3):
            s.step(T)
    assert any("EKF diverged" in line for line in s.log), s.log
    n_log = len(s.log)
    with pytest.raises(Exception):       # and it stays stopped, saying why
        s.step(T)
    assert len(s.log) > n_log and "EKF diverged" in s.log[-1]
    for name in ("q_a_hat", "dq_a_hat", "ddq_a_hat", "p_tool_hat"):
        assert np.all(np.isfinite(s.get(name, 2))), name


def test_nan_input_and_bad_parameter_are_named(fmu: Path) -> None:
    s = Slave(fmu)
    s.init()
    s.set(acc_s=(np.nan, 0.0, G))
    with pytest.raises(Exception):
        s.step(T)
    assert any("acc_s" in line for line in s.log), s.log
    bad = Slave(fmu, dict(index_x=3, index_z=3))
    with pytest.raises(Exception):
        bad.init()
    assert any("index_x" in line for line in bad.log), bad.log
