"""Force observers on synthetic signals with a known contact force and a known inertial force."""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common.frames import G
from fmus.common.parameters import ParameterError, validate
from fmus.force_observer import force_observer_math as fom

M = 12.0     # tool mass of the paper (kg)
H = 0.004    # the paper's sample time (s)


def motion(t: np.ndarray, amp: float = 0.05, f: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """A known tool motion on both axes: positions and accelerations, shape (n, 2)."""
    w = 2 * np.pi * f
    # both axes start at rest (the observers start with zero velocity)
    x = np.stack([1.2 + amp * (1 - np.cos(w * t)), 0.9 + 0.5 * amp * np.cos(1.3 * w * t)], axis=1)
    a = np.stack([amp * w * w * np.cos(w * t), -0.5 * amp * (1.3 * w) ** 2 * np.cos(1.3 * w * t)], axis=1)
    return x, a


def contact_force(t: np.ndarray, t0: float = 1.0, level: float = 40.0) -> np.ndarray:
    """A known contact force: zero, then a smooth rise to ``level`` N along x, 5 N along z."""
    s = np.clip((t - t0) / 0.5, 0.0, 1.0)
    ramp = s * s * (3 - 2 * s)
    return np.stack([level * ramp, 5.0 * ramp], axis=1)


def run(cfg: fom.ForceObserverParameters, u: np.ndarray, a: np.ndarray, x: np.ndarray, h: float = H) -> np.ndarray:
    obs = fom.ForceObserverCore(cfg)
    out = np.empty_like(u)
    for k in range(len(u)):
        out[k] = obs.output(u[k], a[k], x[k])
        obs.advance(u[k], a[k], x[k], h)
    return out


def test_world_readings_cancel_gravity_and_rotate():
    rng = np.random.default_rng(1)
    for _ in range(5):
        phi = rng.uniform(-np.pi, np.pi)
        a = rng.normal(size=2) * 3
        f_ext = rng.normal(size=2) * 20          # force ON the tool (ContactEnvironment)
        R = fom.rotation(phi)
        gvec = np.array([0.0, -G])
        f_s = R.T @ (M * (a - gvec) - f_ext)    # ForceTorqueSensor's reading, sensor frame
        acc_s = R.T @ (a - gvec)                 # accelerometer's specific force, sensor frame
        u, a_w = fom.world_readings(f_s, acc_s, phi, M)
        assert_allclose(a_w, a, atol=1e-12)
        assert_allclose(u, -f_ext + M * a, atol=1e-10)           # eq. 1 with F = -f_ext
        assert_allclose(fom.static_force(u, a_w, M), -f_ext, atol=1e-10)


def test_lever_arm_acceleration_vs_finite_differences():
    r = np.array([0.15, -0.04])
    phi = lambda t: 0.3 + 0.4 * np.sin(3.0 * t)
    pos = lambda t: fom.rotation(phi(t)) @ r
    t, d = 0.37, 1e-4
    acc_fd = (pos(t + d) - 2 * pos(t) + pos(t - d)) / d ** 2
    omega = 1.2 * np.cos(3.0 * t)
    alpha = -3.6 * np.sin(3.0 * t)
    assert_allclose(fom.lever_arm_acceleration(phi(t), omega, alpha, r), acc_fd, rtol=1e-5, atol=1e-7)


def test_rotation_maps_tool_x_to_world():
    # phi = 0: tool x is world x; the matrix is orthonormal for any phi
    assert_allclose(fom.rotation(0.0), np.eye(2))
    R = fom.rotation(0.7)
    assert_allclose(R @ R.T, np.eye(2), atol=1e-15)
    assert_allclose(R @ [1.0, 0.0], [np.cos(0.7), -np.sin(0.7)])


def test_static_left_inverse_properties():
    """Eqs. 8-10: D_F^+ D_F = 1 and D_F^+ C = 0, so D_F^+ (y - D_u u) = F exactly."""
    mats = fom.model_matrices(M)
    rng = np.random.default_rng(2)
    for R in (None, np.diag([1e-8, 0.01])):
        P = fom.force_left_inverse(mats["D_F"], R)
        assert_allclose(P @ mats["D_F"], [[1.0]])
        assert_allclose(P @ mats["C"], np.zeros((1, 2)), atol=1e-12)
        xi, u, F = rng.normal(size=(2, 1)), rng.normal(), rng.normal()
        y = mats["C"] @ xi + mats["D_u"] * u + mats["D_F"] * F
        assert_allclose(P @ (y - mats["D_u"] * u), [[F]], atol=1e-12)


@pytest.mark.parametrize("kind", fom.OBSERVER_KINDS)
def test_steady_contact_force_recovered(kind):
    t = np.arange(0, 4.0, H)
    x, a = motion(t, amp=0.01)
    F = contact_force(t)
    u = F + M * a
    F_hat = run(fom.ForceObserverParameters(observer=kind, m_tool=M), u, a, x)
    late = t > 3.0
    assert_allclose(F_hat[late], F[late], rtol=0, atol=0.02 * 40.0)


@pytest.mark.parametrize("kind", ["static", "kalman"])
def test_unbiased_observers_exact_without_noise(kind):
    """Eqs. 10 and 18: without noise the static and the dynamic observer give F exactly."""
    t = np.arange(0, 2.0, H)
    x, a = motion(t)
    F = contact_force(t, t0=0.5)
    F_hat = run(fom.ForceObserverParameters(observer=kind, m_tool=M), F + M * a, a, x)
    assert_allclose(F_hat, F, atol=1e-9)


def test_kalman_estimate_equals_static_and_filter_is_stable():
    """With D_F^+ C = 0 and D_F^+ D_u = 0, eq. 19 is the static estimate (eqs. 22 = 24)."""
    rng = np.random.default_rng(3)
    n = 500
    u, a, x = rng.normal(size=(n, 2)) * 30, rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    cfg = fom.ForceObserverParameters(observer="kalman", m_tool=M)
    assert_allclose(run(cfg, u, a, x), fom.static_force(u, a, M), atol=1e-9)
    K = fom.kalman_gain(M, H, cfg.sigma_f, cfg.sigma_x, cfg.sigma_a)
    Phi = np.array([[1.0, H], [0.0, 1.0]])
    assert np.max(np.abs(np.linalg.eigvals(Phi - K @ fom.model_matrices(M)["C"]))) < 1.0


def test_kalman_tracks_tool_position():
    t = np.arange(0, 2.0, H)
    x, a = motion(t)
    obs = fom.ForceObserverCore(fom.ForceObserverParameters(observer="kalman", m_tool=M))
    obs.reset(x[0] + 0.01)                   # 10 mm initial error
    u = M * a                                # free space
    for k in range(len(t)):
        obs.output(u[k], a[k], x[k])
        obs.advance(u[k], a[k], x[k], H)
    # after the step the state is the prediction for t[-1] + H
    w = 2 * np.pi * 2.0
    x_next = 1.2 + 0.05 * (1 - np.cos(w * (t[-1] + H)))
    assert abs(obs.position()[0] - x_next) < 1e-4


def test_noise_covariance_eq22():
    """Eqs. 22/24: the static (and dynamic) estimate's variance is m^2 sigma_a^2 + sigma_u^2."""
    rng = np.random.default_rng(7)
    n = 40000
    sa, su = 0.05, 0.3
    a_true = np.zeros((n, 2))
    u = rng.normal(size=(n, 2)) * su
    a = a_true + rng.normal(size=(n, 2)) * sa
    err = fom.static_force(u, a, M)
    assert_allclose(err.var(axis=0), M * M * sa * sa + su * su, rtol=0.03)


def test_zoh_of_double_integrator():
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    Phi, Gam = fom.zoh(A, B, 0.01)
    assert_allclose(Phi, [[1.0, 0.01], [0.0, 1.0]], atol=1e-15)
    assert_allclose(Gam, [[0.5e-4], [0.01]], atol=1e-15)


def test_lowpass_error_tf_matches_eq32_for_k23_one():
    s = 1j * np.logspace(-1, 2, 7)
    k11, k13, k21 = 0.38, -0.0073, 9.05
    H_s = fom.lowpass_error_tf(k11, k13, k21, 1.0, M, s)
    assert_allclose(H_s, k21 * k13 * s / (s * s + k11 * s + k21), rtol=1e-12)
    assert abs(fom.lowpass_error_tf(k11, k13, k21, 0.6, M, 0.0)) < 1e-15   # zero at s = 0


@pytest.mark.parametrize("k23", [1.0, 0.5])
def test_lowpass_frequency_response_matches_eq32(k23):
    """A sinusoidal contact force: the simulated error amplitude is |H(j w)| F0."""
    k11, k13, k21 = 4.0, -0.02, 100.0
    f, F0, h = 1.5, 10.0, 0.0005
    t = np.arange(0, 12.0, h)
    w = 2 * np.pi * f
    F = np.stack([F0 * np.sin(w * t), np.zeros_like(t)], axis=1)
    x, a = motion(t, amp=0.0)                 # the tool held still: the force alone drives it
    cfg = fom.ForceObserverParameters(observer="lowpass", m_tool=M, k11=k11, k13=k13, k21=k21, k23=k23)
    err = F[:, 0] - run(cfg, F + M * a, a, x, h)[:, 0]
    late = t > 8.0
    # least-squares amplitude and phase of the error at the forcing frequency
    basis = np.stack([np.sin(w * t[late]), np.cos(w * t[late])], axis=1)
    cs, *_ = np.linalg.lstsq(basis, err[late], rcond=None)
    H_sim = (cs[0] + 1j * cs[1]) / F0
    H_ref = complex(fom.lowpass_error_tf(k11, k13, k21, k23, M, 1j * w))
    assert abs(H_sim - H_ref) < 0.01 * max(abs(H_ref), 0.05)


def test_lowpass_removes_accelerometer_bias():
    t = np.arange(0, 8.0, H)
    x, a = motion(t, amp=0.02)
    F = contact_force(t)
    bias = np.array([0.2, -0.15])
    u = F + M * a
    late = t > 7.0
    # gains whose bias transient (0.6 Hz, damping 0.75) is over within the run
    lp = run(fom.ForceObserverParameters(observer="lowpass", m_tool=M, k11=6.0, k21=16.0), u, a + bias, x)
    st = run(fom.ForceObserverParameters(observer="static", m_tool=M), u, a + bias, x)
    assert_allclose(st[late], F[late] - M * bias, atol=1e-9)
    assert_allclose(lp[late], F[late], atol=0.1)   # static is off by m*bias = 2.4 N; 0.06 N is the ZOH lag


def test_lowpass_k23_attenuates_accelerometer_noise():
    rng = np.random.default_rng(11)
    t = np.arange(0, 20.0, H)
    n = len(t)
    x = np.zeros((n, 2))
    noise = rng.normal(size=(n, 2)) * 0.1
    u = np.zeros((n, 2))
    k23 = 0.2
    lp = run(fom.ForceObserverParameters(observer="lowpass", m_tool=M, k11=20.0, k13=0.0, k21=100.0, k23=k23), u, noise, x)
    st = run(fom.ForceObserverParameters(observer="static", m_tool=M), u, noise, x)
    ratio = lp[n // 4:].std() / st[n // 4:].std()
    assert ratio < 1.2 * k23


@pytest.mark.parametrize("kind", fom.OBSERVER_KINDS)
def test_free_space_inertial_force_removed(kind):
    """Free-space acceleration, true contact force zero: RMS estimate <= 20 % of raw RMS."""
    rng = np.random.default_rng(5)
    t = np.arange(0, 3.0, H)
    x, a = motion(t, amp=0.05, f=2.0)
    u = M * a + rng.normal(size=a.shape) * 0.5          # force sensor noise 0.5 N
    a_meas = a + rng.normal(size=a.shape) * 0.02          # accelerometer noise
    x_meas = x + rng.normal(size=x.shape) * 1e-5
    F_hat = run(fom.ForceObserverParameters(observer=kind, m_tool=M), u, a_meas, x_meas)
    rms_raw = np.sqrt(np.mean(np.sum(u ** 2, axis=1)))
    rms_hat = np.sqrt(np.mean(np.sum(F_hat ** 2, axis=1)))
    assert rms_hat <= 0.2 * rms_raw


def test_reading_fault_codes():
    ok = np.array([1.0, 2.0, 3.0])
    assert fom.reading_fault(ok, ok, 100.0, 50.0) == fom.FAULT_NONE
    assert fom.reading_fault(np.array([1.0, 100.0, 0.0]), ok, 100.0, 50.0) == fom.FAULT_SATURATED
    assert fom.reading_fault(ok, np.array([0.0, -50.0, 0.0]), 100.0, 50.0) == fom.FAULT_SATURATED
    assert fom.reading_fault(np.array([np.nan, 0, 0]), ok, 100.0, 50.0) == fom.FAULT_NOT_FINITE
    assert fom.reading_fault(ok, np.array([0, np.inf, 0]), 100.0, 50.0) == fom.FAULT_NOT_FINITE


def test_bad_config_rejected():
    with pytest.raises(ParameterError, match="'observer'.*magic"):
        validate(fom.ForceObserverParameters(observer="magic"))
    with pytest.raises(ParameterError, match="'m_tool'"):
        validate(fom.ForceObserverParameters(m_tool=0.0))
