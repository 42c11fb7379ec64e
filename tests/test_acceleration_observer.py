"""AccelerationObserver: pole placement, acceleration from the accelerometer, tracking, the drift
fix, and the FMU (Henriksson et al. 2009, section III-B)."""
from __future__ import annotations

import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.frames import G
from fmus.common.parameters import ParameterError, validate
from fmus.common.robot_params import RobotParameters
from fmus.estimators import acceleration_observer_model as om

P = om.AccelerationObserverParameters


def _match(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    """``got`` reordered to pair each wanted value with its nearest (each used once)."""
    got = list(got)
    out = []
    for w in want:
        i = int(np.argmin([abs(g - w) for g in got]))
        out.append(got.pop(i))
    return np.array(out)


@pytest.mark.parametrize("freqs, dampings", [
    ((0.5, 2.0, 0.5, 2.0), (0.7, 0.7, 0.7, 0.7)),
    ((3.0, 12.0, 4.0, 25.0), (0.3, 0.9, 1.5, 0.1)),
    ((0.2, 60.0, 1.0, 40.0), (2.0, 0.5, 0.7, 3.0)),
])
def test_error_dynamics_have_the_given_poles(freqs, dampings) -> None:
    p = P(pole_freq=freqs, pole_damping=dampings)
    M = om.closed_loop_matrix(p)
    want = om.poles(freqs, dampings)
    assert_allclose(_match(np.linalg.eigvals(M), want), want, rtol=1e-8)
    # per joint: the characteristic polynomial itself
    for i in range(2):
        blk = M[4 * i:4 * i + 4, 4 * i:4 * i + 4]
        assert_allclose(np.poly(blk), om.characteristic_polynomial(freqs[2 * i:2 * i + 2],
                                                                   dampings[2 * i:2 * i + 2]), rtol=1e-8)
    # the discretisation keeps them: eig(Phi) = exp(lambda T)
    T = 5e-4
    Phi, G0, G1 = om.discretise(p, T)
    assert_allclose(_match(np.linalg.eigvals(Phi), np.exp(want * T)), np.exp(want * T), rtol=1e-10)


def test_repeated_poles_and_stiffness_scale() -> None:
    """Four equal real poles per joint (Ackermann copes), also with the model's stiffness halved."""
    for scale in (1.0, 0.5):
        p = P(pole_freq=(1.0,) * 4, pole_damping=(1.0,) * 4, stiffness_scale=scale)
        M = om.closed_loop_matrix(p)
        for i in range(2):
            assert_allclose(np.poly(M[4 * i:4 * i + 4, 4 * i:4 * i + 4]),
                            om.characteristic_polynomial((1.0, 1.0), (1.0, 1.0)), rtol=1e-8)
    A, _, _ = om.joint_matrices(om.model_robot(P(stiffness_scale=0.5)), 0)
    A1, _, _ = om.joint_matrices(om.model_robot(P()), 0)
    assert_allclose(A[3, 0:2], 0.5 * A1[3, 0:2])


def test_measured_arm_acceleration_inverts_the_accelerometer() -> None:
    p = RobotParameters()
    rng = np.random.default_rng(0)
    for _ in range(5):
        q, dq, ddq = rng.uniform(-0.6, 0.6, 2), rng.uniform(-1, 1, 2), rng.uniform(-5, 5, 2)
        f = kinematics.specific_force(q, dq, ddq, p)
        got, mu = om.measured_arm_acceleration(q, dq, f, p, 0.05, 0.05)
        assert mu == 0.0
        assert_allclose(got, ddq, rtol=1e-10, atol=1e-10)


def test_damped_least_squares_near_a_singular_pose() -> None:
    """Exact inverse away from singularities; bounded (|x| <= |b| / (2 mu_max)) at one."""
    J = np.array([[1.0, 0.3], [0.2, 0.8]])
    b = np.array([0.4, -1.0])
    x, mu = om.damped_solve(J, b, 0.05, 0.05)
    assert mu == 0.0
    assert_allclose(x, np.linalg.solve(J, b), rtol=1e-12)
    Js = np.array([[1.0, 2.0], [0.5, 1.0]])          # rank 1
    x, mu = om.damped_solve(Js, b, 0.05, 0.05)
    assert mu == pytest.approx(0.05)
    assert np.all(np.isfinite(x)) and np.linalg.norm(x) <= np.linalg.norm(b) / (2 * 0.05)
    # a pose where the sensor Jacobian is singular (elbow vector parallel to the forearm lever)
    from scipy.optimize import brentq
    p = RobotParameters()

    def det(q2: float) -> float:
        return float(np.linalg.det(kinematics.jacobian((0.2, q2), p, "sensor")))
    grid = np.linspace(-math.pi, math.pi, 73)
    k = next(i for i in range(72) if det(grid[i]) * det(grid[i + 1]) < 0)
    q = np.array([0.2, brentq(det, grid[k], grid[k + 1], xtol=1e-14)])
    s = np.linalg.svd(kinematics.jacobian(q, p, "sensor"), compute_uv=False)
    assert s[-1] < 1e-9
    ddq, mu = om.measured_arm_acceleration(q, np.zeros(2), np.array([0.3, G]), p, 0.05, 0.05)
    assert mu > 0 and np.all(np.isfinite(ddq))


def _simulate(p: om.AccelerationObserverParameters, n: int, acc_bias=(0.0, 0.0), excite=True):
    """Plant under a sinusoidal torque (or at rest), noiseless sensors at 2 kHz; the observer
    gets the measurements of t + T at each step. Returns the arm-angle errors (n, 2)."""
    robot = RobotParameters()
    q0 = np.asarray(p.q_a0)
    plant = dynamics.FlexibleRobotModel(robot, q0)
    obs = om.AccelerationObserverModel(p)
    T = 5e-4
    tau0 = dynamics.gravity_torque(q0, robot) / np.array(robot.gear_ratio)
    err = np.empty((n, 2))
    for k in range(n):
        t = k * T
        tau = tau0 + (np.array([2 * math.sin(2 * math.pi * 1.5 * t), 1.5 * math.sin(2 * math.pi * 2.3 * t)])
                      if excite else 0.0)
        plant.step(tau, (0.0, 0.0), T)
        x = plant.x
        f = kinematics.specific_force(x[0:2], x[4:6], plant.arm_acceleration(0.0, 0.0), robot)
        obs.step(x[2:4], np.array([f[0] + acc_bias[0], 0.0, f[1] + acc_bias[1]]), tau, T)
        err[k] = obs.q_a - x[0:2]
    return err


def test_tracks_a_noiseless_motion() -> None:
    """1 s of motion of 0.1-0.3 rad: the estimate stays within 2e-5 rad (tool: 40 um) of the arm."""
    err = _simulate(P(q_a0=(0.3, -0.2)), 2000)
    assert np.abs(err).max() < 2e-5
    err = _simulate(P(q_a0=(0.3, -0.2), pole_freq=(3.0, 12.0, 3.0, 12.0)), 2000)
    assert np.abs(err).max() < 2e-5


def test_drift_fix_removes_an_accelerometer_offset() -> None:
    """At rest with a 0.05 m/s^2 accelerometer bias the paper's observer settles at an offset;
    with the fusion (1 Hz) the estimate returns to the static one (exact at rest)."""
    base = dict(q_a0=(0.3, -0.2))
    plain = _simulate(P(**base), 8000, acc_bias=(0.05, 0.05), excite=False)
    fused = _simulate(P(**base, drift_crossover=1.0), 8000, acc_bias=(0.05, 0.05), excite=False)
    assert np.abs(plain[-1]).max() > 1e-4
    assert np.abs(fused[-1]).max() < 0.02 * np.abs(plain[-1]).max()
    fused2 = _simulate(P(**base, drift_crossover=1.0, drift_order=2), 8000, acc_bias=(0.05, 0.05),
                       excite=False)
    assert np.abs(fused2[-1]).max() < 0.02 * np.abs(plain[-1]).max()


def test_parameter_errors_name_the_parameter() -> None:
    with pytest.raises(ParameterError, match="index_x"):
        validate(P(index_x=3, index_z=3))
    with pytest.raises(ParameterError, match="pole_damping"):
        validate(P(pole_damping=(0.7, 0.0, 0.7, 0.7)))
    with pytest.raises(ParameterError, match="drift_order"):
        validate(P(drift_order=3))


@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["AccelerationObserver"]


def test_fmu_at_rest_and_parameters(fmu) -> None:
    """Fed the equilibrium measurements, the FMU stays at the initial pose; units and
    descriptions are declared; a bad parameter fails initialisation."""
    robot = RobotParameters()
    q0 = (0.3, -0.2)
    x0 = dynamics.static_equilibrium(q0, robot)
    f = kinematics.specific_force(q0, (0, 0), (0, 0), robot)
    tau = dynamics.gravity_torque(q0, robot) / np.array(robot.gear_ratio)
    start = {"q_a0[1]": q0[0], "q_a0[2]": q0[1], "q_m_meas[1]": x0[2], "q_m_meas[2]": x0[3],
             "acc_s[1]": f[0], "acc_s[2]": 0.0, "acc_s[3]": f[1], "tau_m[1]": tau[0], "tau_m[2]": tau[1],
             "drift_crossover": 1.0}
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.05, step_size=5e-4, start_values=start,
                            output=["p_tool_hat[1]", "p_tool_hat[2]", "q_a_hat[1]", "q_a_hat[2]"])
    assert_allclose([res["q_a_hat[1]"][-1], res["q_a_hat[2]"][-1]], q0, atol=1e-7)
    assert_allclose([res["p_tool_hat[1]"][-1], res["p_tool_hat[2]"][-1]],
                    kinematics.tool_position(q0, robot), atol=1e-6)
    md = fmpy.read_model_description(str(fmu))
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real" and v.causality in ("input", "output"):
            assert v.unit, v.name
    with pytest.raises(Exception):
        fmpy.simulate_fmu(str(fmu), stop_time=0.01, step_size=5e-4, start_values={"pole_damping[2]": -1.0})
