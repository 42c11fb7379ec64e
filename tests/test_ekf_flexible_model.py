"""The three EKFs of Henriksson et al. (2009), section III-A: model, Jacobians, measurement
functions and filtering on a closed-loop simulation of our plant."""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.frames import G, rot_rpy
from fmus.common.kalman import FilterDivergence
from fmus.common.parameters import ParameterError
from fmus.common.robot_params import RobotParameters
from fmus.estimators import henriksson2009_model as hm
from fmus.estimators import ekf_flexible_model as em
import ekf_flexible_truth as truth

P = RobotParameters()


def _states(n: int = 6, seed: int = 1) -> list[np.ndarray]:
    """States around the workspace: gearbox deflections inside and beyond the soft zone
    (``delta`` = 2e-4 rad), motor speeds inside and beyond the friction smoothing (0.5 rad/s)."""
    rng = np.random.default_rng(seed)
    r = np.asarray(P.gear_ratio)
    out = []
    for k in range(n):
        q = rng.uniform(-0.8, 0.8, 2)
        D = rng.choice([1e-4, -5e-5, 1e-3, -2e-3], 2)
        dq = rng.normal(0.0, 0.5, 2)
        dqm = r * dq + rng.normal(0.0, 0.3 if k % 2 else 20.0, 2)
        out.append(np.concatenate([q, r * (q + D), dq, dqm]))
    return out


def _fd(fun, x: np.ndarray, rel: float = 1e-7) -> np.ndarray:
    """Central finite differences of ``fun`` at ``x`` (column per state)."""
    cols = []
    for j in range(len(x)):
        h = rel * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        cols.append((np.asarray(fun(xp)) - np.asarray(fun(xm))) / (2 * h))
    return np.column_stack(cols)


# ---- the model is the plant's --------------------------------------------------------------------
def test_model_is_the_plants_dynamics_without_tool_force() -> None:
    fm = hm.FlexibleModel(P)
    for x in _states():
        u = (1.3, -0.4)
        assert_allclose(fm.f(tuple(x), u), dynamics.derivatives(x, u, (0.0, 0.0), P), rtol=1e-14)


def test_stiffness_scale_scales_the_model_springs() -> None:
    p = em.EkfMotorParameters(stiffness_scale=0.5, k_hi=(8e5, 3e5))
    r = p.model_robot()
    assert_allclose(r.k_hi, (4e5, 1.5e5))
    assert_allclose(r.k_lo, np.asarray(P.k_lo) * 0.5)
    assert em.EkfMotorParameters().model_robot().k_hi == P.k_hi


# ---- Jacobians against finite differences ----------------------------------------------------------
def test_dynamics_jacobian_matches_finite_differences() -> None:
    fm = hm.FlexibleModel(P)
    u = (2.0, -1.0)
    for x in _states():
        A = fm.jacobian(tuple(x), u)
        A_fd = _fd(lambda z: fm.f(tuple(z), u), x)
        # central differences err by O(h^2 f'''): relative to the column scale
        scale = np.abs(A_fd).max(axis=0) + 1.0
        assert_allclose(A / scale, A_fd / scale, rtol=0, atol=1e-6)
        # and the error shrinks as h^2 (an analytic error would not)
        A_fd2 = _fd(lambda z: fm.f(tuple(z), u), x, rel=1e-6)
        assert np.abs(A - A_fd).max() <= np.abs(A - A_fd2).max() + 1e-6


def _augmented(ekf, x: np.ndarray, k: int = 0) -> np.ndarray:
    """``x`` with drift-correction states appended: velocity errors of some mm/s and a log
    stiffness factor off 1 (as ``ekf`` has them)."""
    extra = [3e-3 * (k + 1), -2e-3][: 2 * ekf._tilt] + [0.3 - 0.2 * k][: ekf._stiff]
    return np.concatenate([x, extra])


def _filter(variant: str, correction: str, **params):
    """``make_filter`` with EKF Integrated's ``drift_correction`` or, for EKF Complete,
    ``correction == "stiffness"``: its ``estimate_stiffness``."""
    if variant == "integrated":
        params["drift_correction"] = correction
    elif correction == "stiffness":
        params["estimate_stiffness"] = True
    return em.make_filter(variant, **params)


@pytest.mark.parametrize("variant,correction", [(v, "off") for v in em.VARIANTS]
                         + [("integrated", "tilt"), ("integrated", "tilt_stiffness"),
                            ("complete", "stiffness")])
def test_measurement_jacobian_matches_finite_differences(variant: str, correction: str) -> None:
    ekf = _filter(variant, correction)
    u = (0.7, 0.2)
    for k, x in enumerate(_states()):
        x = _augmented(ekf, x, k % 3)
        H = ekf.h_jacobian(x, u)
        H_fd = _fd(lambda z: ekf.h(z, u), x)
        scale = np.abs(H_fd).max(axis=1, keepdims=True) + 1.0
        assert_allclose(H / scale, H_fd / scale, rtol=0, atol=1e-6)


def test_transition_is_euler_forward() -> None:
    ekf = em.make_filter("motor")
    T = 5e-4
    for x in _states(3):
        u = (0.5, -0.5)
        assert_allclose(ekf.transition(x, u, T), x + T * dynamics.derivatives(x, u, (0, 0), P), rtol=1e-14)
        A_fd = _fd(lambda z: ekf.transition(z, u, T), x)
        assert_allclose(ekf.transition_jacobian(x, u, T), A_fd, rtol=1e-6, atol=1e-6 * T * 1e3)


@pytest.mark.parametrize("variant,correction", [("integrated", "tilt"), ("integrated", "tilt_stiffness"),
                                                ("complete", "stiffness")])
def test_drift_correction_transition_jacobian_matches_finite_differences(variant: str,
                                                                       correction: str) -> None:
    """The augmented transition (velocity-error states ``b' = (R(phi_used) - R(phi)) rho_s``,
    log stiffness factor scaling the spring torque) against finite differences, at tool angles
    off ``phi_used`` and with a hammer-sized specific force."""
    ekf = _filter(variant, correction)
    T = 5e-4
    u = (0.5, -0.5)
    for k, x in enumerate(_states(4)):
        x = _augmented(ekf, x, k % 3)
        aux = (x[0] + x[1] + 0.02 * (k - 1), 30.0 - 10 * k, G + 5 * k)
        A = ekf.transition_jacobian(x, u, T, aux)
        A_fd = _fd(lambda z: ekf.transition(z, u, T, aux), x)
        scale = np.abs(A_fd).max(axis=0) + 1.0
        assert_allclose(A / scale, A_fd / scale, rtol=0, atol=1e-6)
        if correction == "tilt":
            assert A.shape == (10, 10)
        else:
            assert np.abs(A[4:8, -1]).max() > 1e-3       # the stiffness column is exercised
    if variant == "complete":
        assert A.shape == (9, 9)
        return
    # the values: b integrates (R(phi_used) - R(phi)) rho_s; phi = phi_used leaves b alone
    x = _augmented(ekf, _states(1)[0])
    phi = x[0] + x[1]
    xn = ekf.transition(x, u, T, (phi, 3.0, 9.0))
    assert_allclose(xn[8:10], x[8:10], rtol=0, atol=1e-15)
    xn = ekf.transition(x, u, T, (phi + 0.1, 0.0, G))
    R = lambda a: np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])   # noqa: E731
    assert_allclose(xn[8:10] - x[8:10], T * (R(phi + 0.1) - R(phi)) @ (0.0, G), rtol=1e-12)


@pytest.mark.parametrize("correction", ["off", "tilt_stiffness"])
def test_substeps_are_euler_steps_of_the_shorter_step(correction: str) -> None:
    """``substeps = k``: the state takes k Euler steps of T / k (here checked against k single
    steps of a ``substeps = 1`` filter); ``A`` stays ``I + T df/dx`` at the start."""
    one = em.make_filter("integrated", drift_correction=correction)
    four = em.make_filter("integrated", drift_correction=correction, substeps=4)
    T, u = 5e-4, (0.4, -0.3)
    for k, x in enumerate(_states(3)):
        x = _augmented(one, x, k)
        aux = (x[0] + x[1] + 0.01, 5.0, 9.0)
        z = x
        for _ in range(4):
            z = one.transition(z, u, T / 4, aux)
        assert_allclose(four.transition(x, u, T, aux), z, rtol=1e-13, atol=1e-13)
        assert_allclose(four.transition_jacobian(x, u, T, aux), one.transition_jacobian(x, u, T, aux),
                        rtol=1e-12, atol=1e-12)
        assert np.abs(four.transition(x, u, T, aux) - one.transition(x, u, T, aux)).max() > 1e-9


def test_stiffness_factor_state_scales_the_spring() -> None:
    """``f`` with the factor ``sigma = exp(s)`` is the plant's dynamics with ``k_lo``, ``k_hi``
    times ``sigma`` (the spring torque is linear in them; the damping is not scaled)."""
    from fmus.common.parameters import replace
    ekf = em.make_filter("integrated", drift_correction="tilt_stiffness")
    sig = 1.7
    p2 = replace(P, k_lo=tuple(sig * k for k in P.k_lo), k_hi=tuple(sig * k for k in P.k_hi))
    for x in _states(3):
        xa = np.concatenate([x, [0.0, 0.0, math.log(sig)]])
        u = (0.3, -0.8)
        assert_allclose(ekf.model_derivatives(xa, u), dynamics.derivatives(x, u, (0.0, 0.0), p2),
                        rtol=1e-11, atol=1e-9)
        assert_allclose(ekf.transition(xa, u, 5e-4)[0:8],
                        x + 5e-4 * dynamics.derivatives(x, u, (0.0, 0.0), p2), rtol=1e-12, atol=1e-12)
    assert_allclose(ekf.stiffness_factor(xa), sig, rtol=1e-14)
    assert em.make_filter("integrated").stiffness_factor() == 1.0


def test_noise_follows_the_lambda_parameterisation() -> None:
    """Section III-C: lambda1..4 scale the q_a, q_m, dq_a, dq_m blocks of Q, lambda5 the
    motor-angle block of R; the second measurement block is unscaled."""
    base = em.make_filter("integrated")
    ekf = em.make_filter("integrated", lambda1=2.0, lambda2=3.0, lambda3=5.0, lambda4=7.0, lambda5=11.0)
    T = 5e-4
    assert_allclose(np.diag(ekf.process_noise(T)) / np.diag(base.process_noise(T)),
                    [2, 2, 3, 3, 5, 5, 7, 7], rtol=1e-14)
    assert_allclose(np.diag(base.process_noise(T)),
                    T * np.repeat(np.square([1e-4, 1e-4, 1.0, 10.0]), 2), rtol=1e-14)
    assert_allclose(np.diag(ekf.R) / np.diag(base.R), [11, 11, 1, 1], rtol=1e-14)
    assert_allclose(np.diag(em.make_filter("complete").R), [1e-8, 1e-8, 0.05 ** 2, 0.05 ** 2], rtol=1e-14)
    assert em.make_filter("motor").R.shape == (2, 2)
    # the drift-correction states append w_b^2 (x2) and w_stiffness^2, unscaled
    aug = em.make_filter("integrated", drift_correction="tilt_stiffness", w_b=2e-3, w_stiffness=0.1,
                         lambda1=2.0)
    assert_allclose(np.diag(aug.process_noise(T)),
                    T * np.concatenate([np.repeat(np.square([1e-4, 1e-4, 1.0, 10.0]) * [2, 1, 1, 1], 2),
                                        [4e-6, 4e-6, 0.01]]), rtol=1e-14)
    assert aug.R.shape == (4, 4) and aug.P.shape == (11, 11)


# ---- measurement functions (eqs. 6-8) --------------------------------------------------------------
def test_complete_measurement_is_the_accelerometer_through_the_dynamics() -> None:
    ekf = em.make_filter("complete")
    for x in _states():
        ddq = dynamics.arm_acceleration(x, (0.0, 0.0), P)
        f = kinematics.specific_force(x[0:2], x[4:6], ddq, P)
        assert_allclose(ekf.h(x), np.concatenate([x[2:4], f]), rtol=1e-12, atol=1e-12)


def test_integrated_measurement_is_the_sensor_velocity() -> None:
    ekf = em.make_filter("integrated")
    for x in _states():
        v = kinematics.velocity(x[0:2], x[4:6], P, "sensor")
        assert_allclose(ekf.h(x), np.concatenate([x[2:4], v]), rtol=1e-12, atol=1e-15)
    assert_allclose(em.make_filter("motor").h(x), x[2:4])


def test_accelerometer_mount_is_undone() -> None:
    rpy = (0.0, 0.4, math.pi / 2)
    ekf = em.make_filter("complete", mount_rpy=rpy)
    f_tool = np.array([1.5, 0.0, 9.0])
    acc_s = rot_rpy(rpy).T @ f_tool                 # the Imu FMU's reading of f_tool
    assert_allclose(ekf.tool_frame(acc_s), (1.5, 9.0), atol=1e-12)


def test_integrated_velocity_follows_the_true_sensor_velocity() -> None:
    d = truth.simulate()
    ekf = em.make_filter("integrated", q_a0=d["q_a0"])
    n = len(d["t"])
    v = np.zeros((n, 2))
    for k in range(n):
        ekf.update(d["q_m"][k], d["acc_s"][k], d["tau"][k])
        v[k] = ekf.v_int
        ekf.predict(truth.T)
    # trapezoidal integration of exact samples, rotated with the estimated (not the true) angle:
    # during a hammer pulse the trapezoid leads the plant's zero-order-hold force by half a
    # sample (T/2 times tens of m/s^2: about 1.6 mm/s); elsewhere it is exact but for the
    # integral of g times the tool-angle error (the paper's drift: about 1e-5 rad over 3 s
    # gives 0.3 mm/s; measured 0.22 mm/s)
    t = d["t"]
    quiet = np.ones(len(t), bool)
    for t0 in truth.HAMMER_TIMES:
        quiet &= ~((t >= t0) & (t < t0 + truth.HAMMER_DURATION + 0.002))
    err = np.abs(v - d["v_sensor"]).max(axis=1)
    assert np.abs(d["v_sensor"]).max() > 0.5
    assert err[~quiet].max() > 1e-3
    assert err[quiet].max() < 5e-4


# ---- filtering the plant's simulation --------------------------------------------------------------
def _rigid(d: dict) -> np.ndarray:
    r = np.asarray(P.gear_ratio)
    return np.array([kinematics.tool_position(q / r, P) for q in d["q_m"]])


@lru_cache(maxsize=None)
def _run(variant: str, stiffness_scale: float = 1.0, noise: bool = False, correction: str = "off"):
    """The filter after the run and its tool positions (cached)."""
    d = truth.simulate(noise=noise)
    kw = {"drift_correction": correction} if variant == "integrated" else {}
    ekf = em.make_filter(variant, q_a0=d["q_a0"], stiffness_scale=stiffness_scale, **kw)
    return ekf, truth.run_filter(ekf, d)["p_tool"]


@lru_cache(maxsize=None)
def _errors(variant: str, stiffness_scale: float = 1.0, noise: bool = False, correction: str = "off") -> dict:
    """Max and mean tool-position error [m], all frequencies and 3-30 Hz."""
    d = truth.simulate(noise=noise)
    p_hat = _rigid(d) if variant == "rigid" else _run(variant, stiffness_scale, noise, correction)[1]
    return truth.errors(p_hat, d)


@pytest.mark.parametrize("variant", em.VARIANTS)
def test_each_filter_tracks_the_tool_on_a_noiseless_simulation(variant: str) -> None:
    """P1 with three hammer strikes, exact model, no sensor noise: every filter's mean error is
    well below rigid kinematics' (which misses the gearbox deflections: about 4 mm) and the
    3-30 Hz mean error at least 2x lower (the paper's Table I claim)."""
    rigid, e = _errors("rigid"), _errors(variant)
    assert rigid["mean"] > 2e-3
    assert e["mean"] < rigid["mean"] / 10
    assert e["bp_mean"] < rigid["bp_mean"] / 2


@pytest.mark.parametrize("variant", em.VARIANTS)
def test_each_filter_converges_from_a_wrong_initial_estimate(variant: str) -> None:
    d = truth.simulate()
    q0 = np.asarray(d["q_a0"]) + (3e-3, 0.0)       # about 4.5 mm off at the tool
    ekf = em.make_filter(variant, q_a0=tuple(q0), p0_q_a=3e-3, init_from_motors=False)
    assert np.linalg.norm(ekf.tool_position() - d["p_tool"][0]) > 4e-3
    n = int(0.25 / truth.T)
    r = truth.run_filter(ekf, d, n)
    e = np.linalg.norm(r["p_tool"] - d["p_tool"][:n], axis=1)
    print(f"{variant}: tool error {e[0] * 1e3:.3f} mm after the first update, "
          f"{e[-200:].max() * 1e3:.4f} mm max over the last 0.1 s of 0.25 s")
    assert e[-200:].max() < 0.1e-3


@pytest.mark.parametrize("variant", em.VARIANTS)
def test_start_from_the_measured_motor_angles(variant: str) -> None:
    """By default the first update starts at rest in static equilibrium at the measured motor
    angles, whatever q_a0 says: the plant starts at rest in equilibrium, so the first estimate
    is right to the motor-angle resolution (1e-9 rad motor side: 1e-11 rad arm side)."""
    d = truth.simulate()
    ekf = em.make_filter(variant, q_a0=(0.3, 0.3))
    x0 = ekf.initial_state(d["q_m"][0])
    assert_allclose(x0, d["x"][0], rtol=0, atol=1e-9)
    xf = ekf.update(d["q_m"][0], d["acc_s"][0], d["tau"][0])
    assert_allclose(xf[0:2], d["x"][0, 0:2], rtol=0, atol=1e-9)
    assert_allclose(ekf.tool_position(), d["p_tool"][0], rtol=0, atol=1e-8)


def test_stiffness_error_hurts_ekf_motor_most() -> None:
    """The paper's robustness finding (Table I, 'Model errors'): with the filters' stiffness 50 %
    low, EKF Integrated's 3-30 Hz mean error stays well below EKF Motor's. The numbers (noiseless
    P1, default tuning) are printed for the report."""
    rows = {}
    for v in em.VARIANTS:
        rows[v] = (_errors(v)["bp_mean"], _errors(v, 0.5)["bp_mean"])
    rows["rigid"] = (_errors("rigid")["bp_mean"],) * 2
    for v, (a, b) in rows.items():
        print(f"{v:>10}: 3-30 Hz mean error {a * 1e3:.4f} mm nominal, {b * 1e3:.4f} mm with 50 % stiffness")
    assert rows["integrated"][1] < rows["motor"][1] / 2


# ---- EKF Integrated's drift correction (beyond the paper) ----------------------------------------------
def test_tilt_and_a_common_stiffness_factor_determine_the_static_arm_angles() -> None:
    """The observability argument: at rest the accelerometer's gravity direction gives the tool
    angle, hence ``D1 + D2``; a common stiffness factor splits it by the model's ratio. With a
    (nearly) noiseless tilt the static alignment recovers the plant's stiffness (the filter's is
    50 % low: factor 2) and its arm angles to the motor-angle resolution, although the filter's
    own static equilibrium is 3.3 mm off at the tool."""
    d = truth.simulate()
    ekf = em.make_filter("integrated", q_a0=d["q_a0"], stiffness_scale=0.5, drift_correction="tilt_stiffness",
                         r_tilt=1e-7)
    x0 = ekf.initial_state(d["q_m"][0])
    assert np.linalg.norm(ekf.tool_position(x0) - d["p_tool"][0]) > 3e-3
    x, P0 = ekf.static_alignment(d["q_m"][0], d["acc_s"][0])
    assert_allclose(ekf.stiffness_factor(x), 2.0, rtol=1e-5)
    assert_allclose(x[0:8], d["x"][0], rtol=0, atol=1e-8)
    assert np.sqrt(P0[10, 10]) < 1e-3 * 0.35 and np.all(np.linalg.eigvalsh(P0) > 0)
    # with the accelerometer's noise as r_tilt (default 2e-3 rad) the start moves part of the way
    ekf = em.make_filter("integrated", q_a0=d["q_a0"], stiffness_scale=0.5, drift_correction="tilt_stiffness")
    x = ekf.update(d["q_m"][0], d["acc_s"][0], d["tau"][0])
    assert 1.0 < ekf.stiffness_factor(x) < 2.0
    assert np.linalg.norm(ekf.tool_position(x) - d["p_tool"][0]) < 2.5e-3


def test_drift_correction_with_50_percent_stiffness_error() -> None:
    """P1 (noiseless) with the filter's stiffness 50 % low: the paper's EKF Integrated has an
    all-frequency mean error worse than rigid kinematics (4.9 vs 3.9 mm); with ``tilt_stiffness``
    it is about 12x better than rigid kinematics (0.31 mm; asserted 5x), its max error (the
    start) below rigid kinematics' max, its 3-30 Hz mean error below the paper's filter's (0.023
    vs 0.032 mm; the band gain over rigid kinematics is 8x, asserted the paper's 2x), and the
    stiffness factor converges to within 2 % of the plant's (asserted 5 %)."""
    rigid, off = _errors("rigid"), _errors("integrated", 0.5)
    fix = _errors("integrated", 0.5, correction="tilt_stiffness")
    assert off["mean"] > rigid["mean"]                   # the paper's drift problem, reproduced
    assert fix["mean"] < rigid["mean"] / 5
    assert fix["max"] < rigid["max"]
    assert fix["bp_mean"] < rigid["bp_mean"] / 2
    assert fix["bp_mean"] < off["bp_mean"]
    ekf = _run("integrated", 0.5, correction="tilt_stiffness")[0]
    assert_allclose(0.5 * ekf.stiffness_factor(), 1.0, rtol=0.05)


def test_drift_correction_nominal() -> None:
    """P1 (noiseless), exact stiffness: with ``tilt_stiffness`` the all-frequency mean error stays
    far below rigid kinematics' (0.042 vs 3.9 mm; asserted 10x, like the paper's filter) and below
    the paper's filter's (0.064 mm); the 3-30 Hz gain over rigid kinematics is kept (16x; asserted
    the paper's 2x) at the price of a 3-30 Hz mean error about 1.3x the paper's filter's (the
    stiffness factor wanders by 3 % in the first motion; asserted below 1.6x). ``tilt`` alone is
    the best nominal variant (0.026 / 0.0076 mm) but no help with a stiffness error (3.7 mm: see
    ``python tests/ekf_flexible_truth.py``)."""
    rigid, off = _errors("rigid"), _errors("integrated")
    fix = _errors("integrated", correction="tilt_stiffness")
    tilt = _errors("integrated", correction="tilt")
    assert fix["mean"] < rigid["mean"] / 10 and fix["mean"] < off["mean"]
    assert fix["max"] < rigid["max"] / 10
    assert fix["bp_mean"] < rigid["bp_mean"] / 2
    assert fix["bp_mean"] < 1.6 * off["bp_mean"]
    assert tilt["mean"] < off["mean"] and tilt["bp_mean"] < off["bp_mean"]


@pytest.mark.slow
def test_euler_substeps_remove_most_of_the_nominal_error() -> None:
    """The nominal error of the exact-model filter is Euler's first-order error: 4 sub-steps cut
    EKF Integrated's all-frequency and 3-30 Hz mean errors about 4x (0.064 -> 0.014 mm,
    0.0094 -> 0.0023 mm; asserted 3x). Slow only for the module's time budget (2 s); the fast
    test_substeps_are_euler_steps_of_the_shorter_step covers the code."""
    d = truth.simulate()
    ekf = em.make_filter("integrated", q_a0=d["q_a0"], substeps=4)
    e, off = truth.errors(truth.run_filter(ekf, d)["p_tool"], d), _errors("integrated")
    assert e["mean"] < off["mean"] / 3
    assert e["bp_mean"] < off["bp_mean"] / 3


@pytest.mark.slow
def test_drift_correction_with_sensor_noise() -> None:
    """As the two tests above with encoder and accelerometer noise (a second plant simulation:
    about 5 s; noisy numbers: python tests/ekf_flexible_truth.py --noise)."""
    rigid, fix = _errors("rigid", noise=True), _errors("integrated", 1.0, True, "tilt_stiffness")
    half, off_half = _errors("integrated", 0.5, True, "tilt_stiffness"), _errors("integrated", 0.5, True)
    for e in (fix, half):
        assert e["mean"] < rigid["mean"] / 5 and e["max"] < rigid["max"]
        assert e["bp_mean"] < rigid["bp_mean"] / 2
    assert half["bp_mean"] < off_half["bp_mean"]


# ---- divergence and parameters ---------------------------------------------------------------------
def test_divergence_raises_and_keeps_the_estimate() -> None:
    ekf = em.make_filter("complete")
    x0 = ekf.x.copy()
    with pytest.raises(FilterDivergence, match="EKF diverged"):
        for _ in range(5):
            ekf.update(x0[2:4], (1e300, 0.0, 1e300), (0.0, 0.0))
            ekf.predict(5e-4)
    assert np.all(np.isfinite(ekf.x))


def test_bad_parameters_are_named() -> None:
    with pytest.raises(ParameterError, match="lambda3"):
        em.make_filter("motor", lambda3=0.0)
    with pytest.raises(ParameterError, match="stiffness_scale"):
        em.make_filter("integrated", stiffness_scale=-1.0)
    with pytest.raises(ParameterError, match="variant"):
        em.make_filter("complet")
    with pytest.raises(ParameterError, match="drift_correction"):
        em.make_filter("integrated", drift_correction="leak")
    with pytest.raises(ParameterError, match="p0_stiffness"):
        em.make_filter("integrated", p0_stiffness=0.0)
    with pytest.raises(ParameterError, match="substeps"):
        em.make_filter("motor", substeps=0)
    with pytest.raises(TypeError, match="EkfCompleteParameters"):
        em.EkfFlexibleModel(em.EkfMotorParameters(), "complete")
