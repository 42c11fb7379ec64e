"""Physics of the flexible-joint model (2012 paper eqs. 10-11, 2009 paper eq. 2): energy
conservation, static deflection, step convergence, locked-motor resonance, the structure of the
rigid-body terms, the gearbox spring and the external force."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.parameters import as_array, replace
from fmus.common.robot_params import RobotParameters
from fmus.robot_plant.plant_model import PlantParameters

P = RobotParameters()
#: conservative robot: no gearbox damping, no motor friction
P0 = replace(P, d=(0.0, 0.0), f_v=(0.0, 0.0), f_c=(0.0, 0.0))
#: the plant's default integration: 1 ms communication step, the FMU's default RK4 substeps
DT = 1e-3
SUBSTEPS = PlantParameters().substeps
R = as_array(P.gear_ratio)
#: tool positions the paths of the motion controller start from (trajectory.py)
WORK_POINTS = [(1.10, 0.80), (1.45, 0.55), (1.00, 0.60), (1.20, 0.90)]
RNG = np.random.default_rng(7)


def _random_state(rng: np.random.Generator) -> np.ndarray:
    q = rng.uniform(-1.5, 1.5, 2)
    D = rng.uniform(-3e-3, 3e-3, 2)
    return np.concatenate([q, R * (q + D), rng.uniform(-1.0, 1.0, 2), rng.uniform(-100.0, 100.0, 2)])


# ---- (a) energy ----------------------------------------------------------------------------
@pytest.mark.parametrize("q0, dqm0, dq0", [
    ((math.pi, -math.pi / 2), (0.05, -0.03), (0.6, -0.4)),   # hanging, perturbed
    ((0.3, 0.2), (0.0, 0.0), (0.0, 0.0)),                    # working pose: the arm falls
], ids=["hanging", "falling"])
def test_energy_is_conserved_without_friction_and_damping(q0, dqm0, dq0) -> None:
    m = dynamics.FlexibleRobotModel(P0, q0, substeps=SUBSTEPS)
    x = m.x
    x[2:4] += dqm0               # motor angle offset: excites the gearbox modes
    x[4:6] += dq0                # the arm and its motors swing together
    x[6:8] += R * np.asarray(dq0)
    m.x = x
    E0 = dynamics.energy(m.x, P0)
    zero = np.zeros(2)
    drift = 0.0
    travel = 0.0
    for _ in range(10000):
        m.step(zero, zero, DT)
        drift = max(drift, abs(dynamics.energy(m.x, P0) - E0))
        travel = max(travel, float(np.abs(m.x[0:2] - q0).max()))
    assert travel > 0.1                       # the arm really moves
    print(f"relative energy drift over 10 s: {drift / abs(E0):.2e}")
    assert drift / abs(E0) < 1e-6, drift / abs(E0)


def test_energy_balance_with_inputs_damping_and_friction() -> None:
    """dE/dt = tau_m dq_m + (J^T f_ext) dq_a - damping power - friction power (C = skew part)."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        x = _random_state(rng)
        tau, f = rng.uniform(-5.0, 5.0, 2), rng.uniform(-300.0, 300.0, 2)
        xd = dynamics.derivatives(x, tau, f, P)
        h = 1e-7
        dEdt = (dynamics.energy(x + h * xd, P) - dynamics.energy(x - h * xd, P)) / (2 * h)
        dq, dqm = x[4:6], x[6:8]
        Ddot = dqm / R - dq
        power = (tau @ dqm + (kinematics.jacobian(x[0:2], P, "tool").T @ f) @ dq
                 - np.sum(as_array(P.d) * Ddot ** 2) - dynamics.motor_friction(dqm, P) @ dqm)
        assert_allclose(dEdt, power, rtol=1e-6, atol=1e-6 * float(np.abs(xd).max()))


# ---- (b) static deflection -----------------------------------------------------------------
@pytest.mark.parametrize("target", WORK_POINTS[:2])
def test_static_deflection_equals_the_analytic_spring_deflection(target) -> None:
    q_ref = kinematics.inverse_kinematics(target, P)
    m = dynamics.FlexibleRobotModel(P, q_ref, substeps=SUBSTEPS)
    x = m.x
    x[2:4] = R * q_ref          # rigid start: no deflection, the arm must sag
    m.x = x
    qm_ref = R * q_ref
    tau_ff = dynamics.gravity_torque(q_ref, P) / R
    kp, kd = np.array([20.0, 10.0]), np.array([0.5, 0.3])
    for _ in range(8000):
        x = m.x
        tau = tau_ff + kp * (qm_ref - x[2:4]) - kd * x[6:8]
        m.step(tau, np.zeros(2), DT)
    x = m.x
    assert np.abs(x[4:8]).max() < 1e-8          # settled
    q = x[0:2]
    D = x[2:4] / R - q
    D_analytic = dynamics.spring_deflection(dynamics.gravity_torque(q, P), P)
    assert np.abs(D).min() > 1e-4               # not negligible: 0.1 mrad or more
    assert_allclose(D, D_analytic, rtol=0, atol=1e-9)
    # ... which sags the tool by millimetres
    sag = np.linalg.norm(kinematics.tool_position(q, P) - kinematics.tool_position(x[2:4] / R, P))
    assert sag > 1e-3


# ---- (c) step halving ----------------------------------------------------------------------
def test_halving_the_step_changes_the_tool_path_by_less_than_a_micrometre() -> None:
    """Closed loop at 1 kHz (zero-order hold); the plant integrates with 1 ms or 2 x 0.5 ms."""
    q0 = kinematics.inverse_kinematics(WORK_POINTS[0], P)
    a = dynamics.FlexibleRobotModel(P, q0, substeps=SUBSTEPS)
    b = dynamics.FlexibleRobotModel(P, q0, substeps=SUBSTEPS)
    kp, kd = np.array([20.0, 10.0]), np.array([0.5, 0.3])
    f = np.array([0.0, 0.0])
    worst = 0.0
    for k in range(2000):
        t = k * DT
        q_ref = q0 + np.array([0.3, -0.2]) * (1 - math.cos(math.pi * min(t, 1.0))) / 2
        tau = dynamics.gravity_torque(q_ref, P) / R + kp * (R * q_ref - a.x[2:4]) - kd * a.x[6:8]
        if k == 1200:
            f = np.array([150.0, -80.0])       # a force step excites the flexible modes
        a.step(tau, f, DT)
        b.step(tau, f, DT / 2)
        b.step(tau, f, DT / 2)
        worst = max(worst, float(np.linalg.norm(kinematics.tool_position(a.x[0:2], P)
                                                - kinematics.tool_position(b.x[0:2], P))))
    assert np.linalg.norm(kinematics.tool_position(a.x[0:2], P) - kinematics.tool_position(q0, P)) > 0.1
    assert worst < 1e-6, worst


# ---- (d) locked-motor resonance --------------------------------------------------------------
@pytest.mark.parametrize("target", WORK_POINTS)
def test_lowest_locked_motor_resonance_is_between_8_and_15_hz(target) -> None:
    q = kinematics.inverse_kinematics(target, P)
    f = dynamics.locked_motor_frequencies(q, P)
    assert 8.0 < f[0] < 15.0, f
    assert f[1] > f[0]


@pytest.mark.parametrize("q", [(0.0, 0.0), (0.5, 0.3), (-0.3, 0.8)])
def test_locked_motor_frequencies_match_the_linearised_derivatives(q) -> None:
    """Eigenvalues of the finite-difference linearisation of ``derivatives`` with the motor states
    removed (motors locked), undamped."""
    x0 = dynamics.static_equilibrium(q, P0)
    assert_allclose(dynamics.derivatives(x0, dynamics.gravity_torque(q, P0) / R, np.zeros(2), P0),
                    np.zeros(8), atol=1e-9)
    arm = [0, 1, 4, 5]
    A = np.empty((4, 4))
    for j, i in enumerate(arm):
        h = 1e-7
        e = np.zeros(8)
        e[i] = h
        A[:, j] = ((dynamics.derivatives(x0 + e, (0, 0), (0, 0), P0) - dynamics.derivatives(x0 - e, (0, 0), (0, 0), P0))
                   / (2 * h))[arm]
    lam = np.linalg.eigvals(A)
    assert_allclose(lam.real, 0.0, atol=1e-3 * np.abs(lam).max())
    f_lin = np.unique(np.round(np.abs(lam.imag) / (2 * np.pi), 6))
    assert_allclose(f_lin, dynamics.locked_motor_frequencies(q, P0), rtol=1e-5)


# ---- (e) rigid-body terms --------------------------------------------------------------------
def test_mass_matrix_is_symmetric_positive_definite() -> None:
    for q2 in np.linspace(-math.pi, math.pi, 37):
        M = dynamics.mass_matrix([0.3, q2], P)
        assert_allclose(M, M.T, rtol=0, atol=0)
        assert np.linalg.eigvalsh(M).min() > 0.0


def test_mass_matrix_is_the_kinetic_energy_of_the_links() -> None:
    """Point masses and rod inertias of each link, through the kinematics of the centres of mass."""
    q, dq = np.array([0.4, -0.7]), np.array([1.3, -0.6])
    e = kinematics.position(q, P, "elbow")
    ve = kinematics.velocity(q, dq, P, "elbow")
    u = (kinematics.tool_position(q, P) - e) / P.l2
    v_c2 = ve + P.c2 * (kinematics.velocity(q, dq, P, "tool") - ve) / P.l2
    T = 0.5 * P.m1 * (P.c1 / P.l1) ** 2 * ve @ ve + 0.5 * P.I1 * dq[0] ** 2 \
        + 0.5 * P.m2 * v_c2 @ v_c2 + 0.5 * P.I2 * (dq[0] + dq[1]) ** 2
    assert_allclose(0.5 * dq @ dynamics.mass_matrix(q, P) @ dq, T, rtol=1e-12)
    assert_allclose(np.linalg.norm(u), 1.0, rtol=1e-12)


def test_coriolis_equals_christoffel_symbols_of_the_mass_matrix() -> None:
    rng = np.random.default_rng(11)
    h = 1e-6
    for _ in range(8):
        q, dq = rng.uniform(-2, 2, 2), rng.uniform(-3, 3, 2)
        dM = [(dynamics.mass_matrix(q + h * e, P) - dynamics.mass_matrix(q - h * e, P)) / (2 * h) for e in np.eye(2)]
        c = np.array([sum(0.5 * (dM[k][i, j] + dM[j][i, k] - dM[i][j, k]) * dq[j] * dq[k]
                          for j in range(2) for k in range(2)) for i in range(2)])
        assert_allclose(dynamics.coriolis(q, dq, P), c, atol=1e-6)


def test_gravity_torque_is_the_gradient_of_the_potential() -> None:
    rng = np.random.default_rng(5)
    h = 1e-6
    for _ in range(8):
        q = rng.uniform(-3, 3, 2)
        x = np.concatenate([q, R * q, np.zeros(4)])     # no deflection, at rest: E = V
        fd = [(dynamics.energy(x + h * np.r_[e, R * e, np.zeros(4)], P)
               - dynamics.energy(x - h * np.r_[e, R * e, np.zeros(4)], P)) / (2 * h) for e in np.eye(2)]
        assert_allclose(dynamics.gravity_torque(q, P), fd, atol=1e-5)
    # the potential increases upwards: the upper arm vertical (q1 = 0) is the highest
    assert_allclose(dynamics.gravity_torque([0.0, math.pi / 2], P), [0.0, 0.0], atol=1e-12)


# ---- (f) gearbox spring ----------------------------------------------------------------------
def test_spring_deflection_inverts_spring_torque() -> None:
    for tau in ([0.0, 0.0], [1.0, -1.0], [30.0, -20.0], [900.0, -250.0], [-4000.0, 1500.0], [1e-9, -3e-8]):
        D = dynamics.spring_deflection(tau, P)
        assert_allclose(dynamics.spring_torque(-D, np.zeros(2), P), tau, rtol=1e-12, atol=1e-9)


def test_spring_deflection_keeps_its_guess_and_broadcasts() -> None:
    tau = np.array([[900.0, -250.0], [30.0, -20.0]])
    guess = dynamics.spring_deflection(tau, P) * 1.1
    kept = guess.copy()
    D = dynamics.spring_deflection(tau, P, guess)
    np.testing.assert_array_equal(guess, kept)                     # solved in a copy
    assert_allclose(dynamics.spring_torque(-D, np.zeros((2, 2)), P), tau, rtol=1e-12, atol=1e-9)
    one = dynamics.spring_deflection(5.0, P, 0.0)                  # both joints' springs
    assert one.shape == (2,)
    assert_allclose(dynamics.spring_torque(-one, np.zeros(2), P), [5.0, 5.0], rtol=1e-12)


def test_spring_is_softer_near_zero_and_stiffness_is_its_derivative() -> None:
    for D in ([0.0, 0.0], [1e-4, -2e-4], [5e-4, -1e-3], [-3e-3, 4e-3]):
        D = np.asarray(D)
        h = 1e-9
        fd = (dynamics.spring_torque(-(D + h), np.zeros(2), P) - dynamics.spring_torque(-(D - h), np.zeros(2), P)) / (2 * h)
        assert_allclose(dynamics.spring_stiffness(D, P), fd, rtol=1e-6)
    assert_allclose(dynamics.spring_stiffness([0.0, 0.0], P), P.k_lo, rtol=1e-14)
    assert_allclose(dynamics.spring_stiffness([0.05, -0.05], P), P.k_hi, rtol=1e-12)


def test_spring_uses_motor_angle_over_gear_ratio() -> None:
    q_a = np.array([0.2, -0.1])
    D = np.array([1e-3, -2e-3])
    tau = dynamics.spring_torque(q_a, R * (q_a + D), P)
    assert_allclose(dynamics.spring_deflection(tau, P), D, atol=1e-15)
    assert np.all(np.sign(tau) == np.sign(D))


# ---- (g) external force ------------------------------------------------------------------------
def test_external_force_enters_as_jacobian_transpose_by_virtual_work() -> None:
    rng = np.random.default_rng(9)
    h = 1e-6
    for _ in range(8):
        x = _random_state(rng)
        q = x[0:2]
        f = rng.uniform(-500, 500, 2)
        base = dynamics.derivatives(x, (1.0, -1.0), (0.0, 0.0), P)
        with_f = dynamics.derivatives(x, (1.0, -1.0), f, P)
        # virtual work: the generalized force is f . d p_tool / d q
        J_fd = np.column_stack([(kinematics.tool_position(q + h * e, P) - kinematics.tool_position(q - h * e, P))
                                / (2 * h) for e in np.eye(2)])
        assert_allclose(dynamics.mass_matrix(q, P) @ (with_f[4:6] - base[4:6]), J_fd.T @ f, rtol=1e-6,
                        atol=1e-6 * np.abs(f).max())
        assert_allclose(with_f[[0, 1, 2, 3, 6, 7]], base[[0, 1, 2, 3, 6, 7]], rtol=0, atol=0)
        assert_allclose(dynamics.arm_acceleration(x, f, P), with_f[4:6], rtol=0, atol=0)


def test_motor_equation() -> None:
    """Eq. 10: J_m ddq_m = tau_m - F(dq_m) - (tau_s + d Ddot) / r."""
    rng = np.random.default_rng(13)
    for _ in range(5):
        x = _random_state(rng)
        tau = rng.uniform(-5, 5, 2)
        xd = dynamics.derivatives(x, tau, (0.0, 0.0), P)
        t_s = dynamics.spring_torque(x[0:2], x[2:4], P) + as_array(P.d) * (x[6:8] / R - x[4:6])
        assert_allclose(as_array(P.J_m) * xd[6:8], tau - dynamics.motor_friction(x[6:8], P) - t_s / R, rtol=1e-10,
                        atol=1e-10)
        assert_allclose(dynamics.mass_matrix(x[0:2], P) @ xd[4:6] + dynamics.coriolis(x[0:2], x[4:6], P)
                        + dynamics.gravity_torque(x[0:2], P), t_s, rtol=1e-10, atol=1e-8)
        assert_allclose(xd[0:4], x[4:8], rtol=0, atol=0)
