"""Tests of orchestration.crlb: the posterior CRLB of Axelsson et al. (2012), eqs. 7-9, 21-25."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics
from fmus.common.robot_params import RobotParameters
from fmus.estimators import axelsson2012_model as am
from orchestration import crlb


def _triple_integrator(T: float):
    F = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    G = np.array([[T ** 3 / 6], [T * T / 2], [T]])
    return F, G


def _kalman_stationary(F, G, H, Q, R, n_iter=20000):
    """Iterate the Kalman filter's covariance recursion (eq. 3) to convergence."""
    P = np.eye(F.shape[0])
    for _ in range(n_iter):
        Pp = F @ P @ F.T + G @ Q @ G.T
        K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R)
        P_new = Pp - K @ H @ Pp
        if np.max(np.abs(P_new - P)) <= 1e-15 * np.max(np.abs(P)):
            return P_new
        P = P_new
    return P


def test_linear_bound_is_the_kalman_filters_stationary_covariance():
    F, G = _triple_integrator(0.01)
    H = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.array([[2.0]])
    R = np.diag([1e-6, 1e-4])
    P, Pp = crlb.crlb_linear(F, H, Q, R, G, predicted=True)
    assert_allclose(P, _kalman_stationary(F, G, H, Q, R), rtol=1e-8)
    # eq. 7 holds for Pp, eq. 9 links them
    K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R)
    assert_allclose(F @ (Pp - K @ H @ Pp) @ F.T + G @ Q @ G.T, Pp, rtol=1e-9)
    assert_allclose(P, Pp - K @ H @ Pp, rtol=1e-12)


def test_monte_carlo_kalman_filter_attains_the_bound():
    """A Kalman filter on the linear-Gaussian model reaches the bound: the sample variance of
    its errors over M runs matches the bound within the chi-square spread.

    For M independent runs, the sample mean of e_i^2 has relative standard deviation
    sqrt(2/M) (Gaussian errors); with M = 400, that is 7 %; we allow 4 sigma = 28 % per
    state on one time step and compare the time average of the last 50 steps (correlated, so the
    same tolerance still holds conservatively).
    """
    rng = np.random.default_rng(12)
    F, G = _triple_integrator(0.01)
    H = np.array([[1.0, 0.0, 0.0]])
    Q = np.array([[50.0]])
    R = np.array([[1e-6]])
    P = crlb.crlb_linear(F, H, Q, R, G)
    M, steps = 400, 400
    x = np.zeros((M, 3))
    xh = np.zeros((M, 3))
    Pk = np.diag([1e-6, 1e-4, 1e-2])
    # the true initial state drawn from the filter's prior
    x = rng.standard_normal((M, 3)) * np.sqrt(np.diag(Pk))
    err2 = []
    for k in range(steps):
        # predict (common covariance; every run has the same gains)
        if k > 0:
            x = x @ F.T + (rng.standard_normal((M, 1)) * math.sqrt(Q[0, 0])) @ G.T
            xh = xh @ F.T
            Pk = F @ Pk @ F.T + G @ Q @ G.T
        y = x @ H.T + rng.standard_normal((M, 1)) * math.sqrt(R[0, 0])
        K = Pk @ H.T @ np.linalg.inv(H @ Pk @ H.T + R)
        xh = xh + (y - xh @ H.T) @ K.T
        Pk = Pk - K @ H @ Pk
        if k >= steps - 50:
            err2.append(np.mean((xh - x) ** 2, axis=0))
    assert_allclose(Pk, P, rtol=1e-6)                   # the filter's own covariance converged to it
    assert_allclose(np.mean(err2, axis=0), np.diag(P), rtol=0.28)


def test_no_stabilising_solution_is_a_clear_error():
    F = np.diag([1.0, 1.0])
    H = np.array([[1.0, 0.0]])               # the second integrator is not observed
    with pytest.raises(crlb.CrlbError, match="no stabilising solution"):
        crlb.crlb_linear(F, H, np.eye(2), np.eye(1))


def test_bad_shapes_are_a_clear_error():
    with pytest.raises(crlb.CrlbError, match="shape"):
        crlb.crlb_linear(np.eye(3), np.ones((1, 2)), np.eye(3), np.eye(1))


def test_stacked_bounds_match_one_by_one():
    F, G = _triple_integrator(0.01)
    Hs = np.array([[[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.3]]])
    Q, R = np.array([[3.0]]), np.array([[1e-6]])
    P = crlb.crlb_linear(np.stack([F, F]), Hs, Q, R, G)
    for i in range(2):
        assert_allclose(P[i], crlb.crlb_linear(F, Hs[i], Q, R, G), rtol=1e-12)


def test_discretise_of_the_integrator_chain_is_the_ekfs_model():
    """eq. 25 with A_c = integrators gives the EKF's F and G_w of eq. 14."""
    T = 0.01
    A, _ = am.continuous_model(am.Layout(False, False))
    F, G = crlb.discretise(A, T)
    F14, _, Gw = am.transition_matrices(T, am.Layout(False, False))
    assert_allclose(F, F14, atol=1e-15)
    assert_allclose(G, Gw, atol=1e-15)


# ---- the robot model of eqs. 21-24 ------------------------------------------------------------
def _state(p: RobotParameters):
    """A moving state (q_a, dq_a, ddq_a) and input (q_m, dq_m, ddq_m) consistent with eq. 21."""
    q = np.array([0.3, -0.4])
    dq = np.array([0.2, -0.15])
    D = np.array([2e-3, -1.5e-3])
    r = np.asarray(p.gear_ratio)
    qm = r * (q + D)
    dqm = r * (dq + np.array([0.01, -0.02]))
    ddqm = np.array([3.0, -2.0])
    model = crlb.RobotCrlbModel(p)
    ddq = model.acceleration(q, dq, qm, dqm)
    return np.concatenate([q, dq, ddq]), np.concatenate([qm, dqm, ddqm])


def test_acceleration_is_the_plants_arm_acceleration():
    p = RobotParameters()
    x, u = _state(p)
    plant_x = np.concatenate([x[0:2], u[0:2], x[2:4], u[2:4]])
    assert_allclose(crlb.RobotCrlbModel(p).acceleration(x[0:2], x[2:4], u[0:2], u[2:4]),
                    dynamics.arm_acceleration(plant_x, (0.0, 0.0), p), rtol=1e-12)


def test_jerk_is_the_time_derivative_of_the_acceleration():
    """L of eq. 22b against a central difference in time along (dq_a, ddq_a, dq_m, ddq_m)."""
    p = RobotParameters()
    x, u = _state(p)
    m = crlb.RobotCrlbModel(p)
    h = 1e-6

    def k_at(s):
        return m.acceleration(x[0:2] + s * x[2:4], x[2:4] + s * x[4:6], u[0:2] + s * u[2:4], u[2:4] + s * u[4:6])

    assert_allclose(m.jerk(x, u), (k_at(h) - k_at(-h)) / (2 * h), rtol=1e-6)


def test_numerical_linearisation_matches_an_analytic_case():
    """At rest with the springs relaxed, gravity off and a linear spring, the jerk of eq. 22b is
    ``L = M^-1 (K (dq_m/r - dq) + d (ddq_m/r - ddq))`` to first order (the Coriolis terms and the
    derivatives of ``M^-1`` multiply zero velocities or torques), so ``dL/dx`` is known in closed
    form: ``(0, -M^-1 K, -M^-1 d)``."""
    p = RobotParameters(g=0.0, k_lo=(8.0e5, 2.4e5))          # linear spring k_lo = k_hi
    m = crlb.RobotCrlbModel(p)
    x = np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    u = np.array([p.gear_ratio[0] * 0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    A = m.system_matrix(x, u)
    M = dynamics.mass_matrix(x[0:2], p)
    K = np.diag(p.k_hi)
    Dm = np.diag(p.d)
    Minv = np.linalg.inv(M)
    assert_allclose(A[4:6, 2:4], -Minv @ K, rtol=1e-5)
    assert_allclose(A[4:6, 4:6], -Minv @ Dm, rtol=1e-5)
    assert_allclose(A[4:6, 0:2], 0.0, atol=1e-6 * np.abs(Minv @ K).max())
    assert_allclose(A[0:2, 2:4], np.eye(2))
    assert_allclose(A[2:4, 4:6], np.eye(2))


def _trajectory(p, n=6):
    """A short smooth set of states along which to evaluate the bound."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    q = np.array([0.1, 0.2]) + 0.05 * s
    dq = np.array([0.05, -0.04]) * np.ones_like(s)
    D = dynamics.spring_deflection(dynamics.gravity_torque(q, p), p)
    r = np.asarray(p.gear_ratio)
    qm = r * (q + D)
    dqm = r * dq
    ddqm = np.zeros_like(dqm)
    ddq = crlb.RobotCrlbModel(p).acceleration(q, dq, qm, dqm)
    return q, dq, ddq, qm, dqm, ddqm


def test_accelerometer_lowers_the_bound():
    ekf = am.EkfAccelerometerParameters(q_jerk=4e-6, r_motor=0.04, r_acc=1e-4)
    traj = _trajectory(ekf.robot())
    with_acc = crlb.robot_crlb(*traj, 0.01, ekf, True)
    without = crlb.robot_crlb(*traj, 0.01, ekf, False)
    assert with_acc.P.shape == (6, 6, 6)
    # information only adds: P_with <= P_without (positive semi-definite difference) everywhere
    # (compared in the states' own scales: the blocks differ by orders of magnitude)
    for Pw, Po in zip(with_acc.P, without.P):
        s = 1.0 / np.sqrt(np.diag(Po))
        assert np.linalg.eigvalsh(s[:, None] * (Po - Pw) * s).min() >= -1e-9
    assert np.all(with_acc.position < without.position)
    assert np.all(np.isfinite(with_acc.position)) and np.all(with_acc.position > 0)


def test_robot_bound_with_integrator_dynamics_is_the_ekfs_covariance():
    """Consistency: feeding the robot bound's pieces (G, H, Q, R) with the EKF's own F gives the
    covariance the EKF converges to when it linearises at the true state."""
    ekf = am.EkfAccelerometerParameters(q_jerk=1.0, r_motor=0.04, r_acc=1e-4)
    q, dq, ddq, *_ = _trajectory(ekf.robot(), n=1)
    x = np.concatenate([q[0], dq[0], ddq[0]])
    layout = am.Layout(True, False)
    F, _, Gw = am.transition_matrices(0.01, layout)
    H = am.MeasurementModel(ekf.robot(), layout).jacobian(x)
    Q = am.process_noise(ekf, layout)
    R = am.measurement_noise(ekf, layout)
    P = crlb.crlb_linear(F, H, Q, R, Gw)
    assert_allclose(P, _kalman_stationary(F, Gw, H, Q, R), rtol=1e-7)


def test_bad_trajectory_is_a_clear_error():
    ekf = am.EkfAccelerometerParameters()
    q, dq, ddq, qm, dqm, ddqm = _trajectory(ekf.robot(), n=3)
    q = q.copy()
    q[1, 0] = np.nan
    with pytest.raises(crlb.CrlbError, match="non-finite"):
        crlb.robot_crlb(q, dq, ddq, qm, dqm, ddqm, 0.01, ekf, True)
    with pytest.raises(crlb.CrlbError, match="sample period"):
        crlb.robot_crlb(*_trajectory(ekf.robot(), n=3), 0.0, ekf, True)


def test_doubling_solver_matches_scipy():
    ekf = am.EkfAccelerometerParameters(q_jerk=4e-6, r_motor=0.04, r_acc=1e-4)
    traj = _trajectory(ekf.robot())
    a = crlb.robot_crlb(*traj, 0.01, ekf, True, method="doubling")
    b = crlb.robot_crlb(*traj, 0.01, ekf, True, method="scipy")
    s = 1.0 / np.sqrt(np.diagonal(b.P, axis1=1, axis2=2))
    assert_allclose(s[:, :, None] * a.P * s[:, None, :], s[:, :, None] * b.P * s[:, None, :], atol=1e-7)
    F, G = _triple_integrator(0.01)
    H = np.array([[1.0, 0.0, 0.0]])
    assert_allclose(crlb.crlb_linear(np.stack([F, F]), H, np.eye(1), np.eye(1) * 1e-6, G, method="doubling"),
                    crlb.crlb_linear(np.stack([F, F]), H, np.eye(1), np.eye(1) * 1e-6, G), rtol=1e-8)
    with pytest.raises(crlb.CrlbError, match="no stabilising solution"):
        crlb.crlb_linear(np.stack([np.eye(2)]), np.array([[1.0, 0.0]]), np.eye(2), np.eye(1), method="doubling")


# ---- validation: a true system with the process noise the bound assumes -----------------------
def _section4_ekf() -> am.EkfAccelerometerParameters:
    """The EKF of the section-4 scenario (eq. 26's R, motor side), at the square path's start."""
    return am.EkfAccelerometerParameters(p_tool0=(1.2, 0.9), r_motor=1e-6, r_acc=1e-4, use_bias=False)


def _check_validation(v, tol):
    """Matched EKF at the bound (within the Monte Carlo spread ``tol``); no filter clearly below
    the true bound; the overtuned motor-only EKF beats the 'bound' built with its own Q."""
    for name in ("matched_acc", "matched_motor", "overtuned_acc", "overtuned_motor"):
        for g in ("position", "velocity", "acceleration"):
            ratio = v[name]["rmse"][g] / v[name]["crlb_true_q"][g]
            assert ratio >= 1 - tol, (name, g, ratio)
            if name.startswith("matched"):
                assert ratio <= 1 + tol, (name, g, ratio)
    mot = v["overtuned_motor"]
    assert mot["rmse"]["position"] < 0.9 * mot["crlb_filter_q"]["position"]


def test_validation_case_ekf_attains_and_does_not_beat_the_bound():
    """20 runs of 2 s (1.5 s evaluated): the relative spread of the time-averaged RMSE is a few
    per cent (measured 2 % at most), so 7 % separates 'at the bound' from a wrong bound or filter."""
    v = crlb.validation_case(_section4_ekf(), 1.0, 20, stop_time=2.0, after=0.5)
    assert v["runs"] == 20 and len(v["time"]) == 201
    _check_validation(v, 0.07)


@pytest.mark.slow
def test_validation_case_over_100_runs():
    v = crlb.validation_case(_section4_ekf(), 1.0, 100, stop_time=4.0, after=0.5, seed=7)
    _check_validation(v, 0.04)
