"""The Kalman toolkit (fmus/common/kalman.py): the one measurement update, the time update, the
one definiteness test and the estimate check.

The update is checked against the three forms the filters had before it (kept here as the
reference: the 2012 EKF's Cholesky solves, the 2009 EKFs' LAPACK ``potrf``/``potrs`` with a
diagonal ``R``, the IMU EKF's inverse of ``S``) and against closed forms (the scalar Kalman
filter, the information form of the linear-Gaussian posterior).
"""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.linalg.lapack import dpotrf, dpotrs

from fmus.common import kalman
from fmus.common.kalman import FilterDivergence, check_estimate, is_positive_definite, measurement_update

#: (states, measurements) of the filters: the 2012 EKF's layouts, the 2009 trio's, the IMU EKF's
CASES = ((6, 4), (6, 2), (10, 4), (8, 2), (8, 4), (9, 4), (11, 4), (21, 12), (3, 1))


def _problem(n: int, m: int, seed: int):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) * np.logspace(-2, 0, n)       # states of different scales
    P = A @ A.T + 1e-8 * np.eye(n)
    H = rng.normal(size=(m, n))
    R = np.diag(rng.uniform(1e-4, 1e-1, m))
    return rng.normal(size=n), P, rng.normal(size=m), H, R


# ---- the former updates, as the filters had them (the reference) ------------------------------
def _joseph(P, K, H, R):
    IKH = np.eye(P.shape[0]) - K @ H
    Pf = IKH @ P @ IKH.T + K @ R @ K.T
    return 0.5 * (Pf + Pf.T)


def _old_2012(x, P, nu, H, R):
    Sc = np.linalg.cholesky(H @ P @ H.T + R)
    K = np.linalg.solve(Sc.T, np.linalg.solve(Sc, (P @ H.T).T)).T
    z = np.linalg.solve(Sc, nu)
    return x + K @ nu, _joseph(P, K, H, R), z @ z


def _old_2009(x, P, nu, H, R):
    PHt = P @ H.T
    Sc, info = dpotrf(H @ PHt + R, lower=1, clean=0)
    assert info == 0
    KT = dpotrs(Sc, PHt.T, lower=1)[0]
    K = KT.T
    IKH = np.eye(P.shape[0]) - K @ H
    Pf = IKH @ P @ IKH.T + (K * np.diag(R)) @ KT
    return x + K @ nu, 0.5 * (Pf + Pf.T), abs(float(nu @ dpotrs(Sc, nu, lower=1)[0]))


def _old_imu(x, P, nu, H, R):
    PHt = P @ H.T
    S_inv = np.linalg.inv(H @ PHt + R)
    K = PHt @ S_inv
    return x + K @ nu, _joseph(P, K, H, R), float(nu @ S_inv @ nu)


@pytest.mark.parametrize("old", [_old_2012, _old_2009, _old_imu], ids=["ekf2012", "ekf2009", "imu_ekf"])
@pytest.mark.parametrize("n, m", CASES)
def test_update_is_each_filters_former_update(old, n: int, m: int) -> None:
    for seed in range(5):
        x, P, nu, H, R = _problem(n, m, seed)
        xf, Pf, nis = measurement_update(x, P, nu, H, R)
        xo, Po, niso = old(x, P, nu, H, R)
        assert_allclose(xf, xo, rtol=1e-12, atol=1e-12 * np.abs(xo).max())
        assert_allclose(Pf, Po, rtol=1e-12, atol=1e-12 * np.abs(Po).max())
        assert_allclose(nis, niso, rtol=1e-12)
        assert np.array_equal(Pf, Pf.T)


def test_scalar_update_is_the_closed_form() -> None:
    """One state, one measurement: ``K = p h / (h^2 p + r)``, ``p+ = p r / (h^2 p + r)``."""
    for p, h, r, x, nu in ((2.0, 0.5, 0.3, 1.0, -0.7), (1e-6, 3.0, 1e-4, -2.0, 1e-3), (4.0, -1.0, 4.0, 0.0, 2.0)):
        xf, Pf, nis = measurement_update(np.array([x]), np.array([[p]]), np.array([nu]), np.array([[h]]),
                                         np.array([[r]]))
        s = h * h * p + r
        assert_allclose(xf, [x + p * h / s * nu], rtol=1e-15)
        assert_allclose(Pf, [[p * r / s]], rtol=1e-14)
        assert_allclose(nis, nu * nu / s, rtol=1e-15)


@pytest.mark.parametrize("n, m", CASES)
def test_update_is_the_linear_gaussian_posterior(n: int, m: int) -> None:
    """Prior ``N(x, P)``, ``y = H x + v``, ``v ~ N(0, R)``: the posterior in information form,
    ``P+ = (P^-1 + H^T R^-1 H)^-1``, ``x+ = P+ (P^-1 x + H^T R^-1 y)``."""
    rng = np.random.default_rng(n + m)
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)                         # well conditioned: the inverses are exact enough
    H, R = rng.normal(size=(m, n)), np.diag(rng.uniform(0.5, 2.0, m))
    x, y = rng.normal(size=n), rng.normal(size=m)
    xf, Pf, _ = measurement_update(x, P, y - H @ x, H, R)
    info = np.linalg.inv(P) + H.T @ np.linalg.solve(R, H)
    P_post = np.linalg.inv(info)
    assert_allclose(Pf, P_post, rtol=1e-9, atol=1e-12)
    assert_allclose(xf, P_post @ (np.linalg.solve(P, x) + H.T @ np.linalg.solve(R, y)), rtol=1e-9, atol=1e-12)


def test_time_updates() -> None:
    """``F P F^T + Q`` and ``F x + B u`` (symmetrised), against numpy."""
    rng = np.random.default_rng(2)
    for n in (6, 8, 21):
        x, P, _, _, _ = _problem(n, 1, n)
        F = np.eye(n) + 0.01 * rng.normal(size=(n, n))
        B, u = rng.normal(size=(n, 2)), rng.normal(size=2)
        A = rng.normal(size=(n, n))
        Q = 1e-3 * A @ A.T
        Pp = kalman.time_update(F, P, Q)
        ref = F @ P @ F.T + Q
        assert_allclose(Pp, 0.5 * (ref + ref.T), rtol=1e-12, atol=1e-14 * np.abs(ref).max())
        assert np.array_equal(Pp, Pp.T)
        xp, Pl = kalman.linear_time_update(x, P, F, B, u, Q)
        assert_allclose(xp, F @ x + B @ u, rtol=1e-12, atol=1e-14)
        assert np.array_equal(Pl, Pp)


def test_divergence_is_named() -> None:
    x, P, nu, H, R = _problem(6, 4, 0)
    with pytest.raises(FilterDivergence, match="^here: the innovation covariance is not positive definite$"):
        measurement_update(x, P, nu, H, -10 * R - H @ P @ H.T, where="here")
    not_finite = r"^EKF diverged in the measurement update: non-finite innovation \(nu, its covariance S or nu\^T"
    with pytest.raises(FilterDivergence, match=not_finite):
        measurement_update(x, P, np.array([0.0, np.inf, 0.0, 0.0]), H, R)
    with pytest.raises(FilterDivergence, match=not_finite):
        measurement_update(x, P, nu, np.full((4, 6), 1e200), R)
    with pytest.raises(FilterDivergence, match=not_finite):       # finite, but nu^T S^-1 nu overflows
        measurement_update(x, P, np.full(4, 1e250), H, R)
    with pytest.raises(FilterDivergence, match="update: non-finite state or covariance$"):
        measurement_update(np.array([np.nan, 0, 0, 0, 0, 0]), P, nu, H, R)
    with pytest.raises(FilterDivergence, match="^EKF diverged in the time update: the covariance is not positive"):
        kalman.time_update(np.eye(6), P, -2 * P)
    kalman.time_update(np.eye(6), np.zeros((6, 6)), np.zeros((6, 6)), definite=False)   # only finiteness
    with pytest.raises(FilterDivergence, match="non-finite"):
        kalman.time_update(np.eye(6), P, np.full((6, 6), np.nan), definite=False)


def test_positive_definiteness_agrees_with_the_eigenvalues() -> None:
    """Random symmetric matrices: positive definite exactly when the smallest eigenvalue is > 0."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        A = rng.normal(size=(5, 5))
        P = A @ A.T + rng.uniform(-2.0, 2.0) * np.eye(5)
        ev = np.linalg.eigvalsh(P).min()
        if abs(ev) > 1e-9:
            assert is_positive_definite(P) == (ev > 0.0)
    assert not is_positive_definite(np.diag([1.0, np.nan]))


def test_cholesky_is_numpys_to_round_off() -> None:
    rng = np.random.default_rng(5)
    for n in (1, 4, 12):
        A = rng.normal(size=(n, n))
        S = A @ A.T + 0.1 * np.eye(n)
        L = np.zeros((n, n))
        assert kalman.cholesky_kernel(S, L)
        assert_allclose(L, np.linalg.cholesky(S), rtol=1e-13, atol=1e-15)


def test_check_estimate_names_the_cause_and_the_place() -> None:
    x, P = np.zeros(3), np.eye(3)
    check_estimate(x, P, "here")
    with pytest.raises(FilterDivergence, match="^here: non-finite"):
        check_estimate(np.array([0.0, np.nan, 0.0]), P, "here")
    with pytest.raises(FilterDivergence, match="^there: non-finite"):
        check_estimate(x, np.full((3, 3), np.inf), "there")
    indefinite = np.diag([1.0, -1e-3, 1.0])
    with pytest.raises(FilterDivergence, match=r"not positive definite \(smallest eigenvalue -0.001\)"):
        check_estimate(x, indefinite, "here")
    check_estimate(x, indefinite, "here", definite=False)      # only finiteness asked


def test_no_scipy_linalg_at_import() -> None:
    """The toolkit loads without scipy.linalg (about 0.3 s of a run's start-up)."""
    import subprocess
    import sys
    code = "import sys, fmus.common.kalman; print('scipy.linalg' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
