"""Kalman-filter toolkit shared by every (extended) Kalman filter (plain math, no FMI): the one
measurement update, the one time update of the covariance, the one definiteness test and the
one divergence error.

The measurement update (:func:`measurement_update`) is the EKF's of Axelsson, Karlsson and
Norrlöf (2012), eq. 3b, and of Henriksson et al. (2009), eqs. 4-5c, for a linearisation
``y ~ h(x0) + H (x - x0)`` with the innovation ``nu = y - h(x0)``, in this one form::

    S   = H P H^T + R                      innovation covariance
    L   = chol(S)                          lower Cholesky factor (S = L L^T); none: divergence
    K   = P H^T S^-1                       gain, from two triangular solves with L
    x+  = x + K nu
    P+  = (I - K H) P (I - K H)^T + K R K^T    Joseph form (stays symmetric positive definite
                                               for any gain; equal to P - K H P in exact arithmetic)
    P+ <- (P+ + P+^T) / 2                  symmetrised against round-off
    nis = nu^T S^-1 nu = |L^-1 nu|^2       normalised innovation squared

The time update (:func:`time_update`) is ``P+ = F P F^T + Q`` (eq. 3a; Henriksson et al.
eq. 5b), symmetrised the same way, with ``x+ = F x + B u`` for a linear model
(:func:`linear_time_update`, eq. 3a of the 2012 paper).

Positive definiteness is tested in one way everywhere: whether the Cholesky factorisation
exists (every pivot ``> 0``; the same test as LAPACK's ``potrf``), :func:`is_positive_definite`.

The arithmetic is compiled (:func:`fmus.common.jit.kernel`) as plain loops, no BLAS/LAPACK: each
call rounds the same wherever it runs (one filter in an FMU, or a loop over many runs of the
batched engine), and a 6-state update costs a few microseconds instead of tens in numpy. The
``*_kernel`` functions are for other kernels; they return a status (:data:`OK`, ...) instead of
raising, and :func:`raise_for` turns it into the error.
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common.jit import kernel

#: Status codes of the kernels.
OK, INNOVATION_NOT_PD, NOT_FINITE, NOT_PD, INNOVATION_NOT_FINITE = 0, 1, 2, 3, 4


class FilterDivergence(FloatingPointError):
    """The estimate became non-finite or its covariance lost positive definiteness; an estimator
    FMU ends the step with an FMI error naming the cause and holds its last good estimate
    (:class:`fmus.common.filter_adapter.FilterAdapter`)."""


# ---- kernels (loops: the rounding of the source order, no BLAS) -------------------------------
@kernel(aot="boolean(float64[:, :], float64[:, :])")
def cholesky_kernel(S: np.ndarray, L: np.ndarray) -> bool:
    """Write the lower Cholesky factor of the symmetric ``S`` into ``L`` (zero above the
    diagonal on entry); False if a pivot is not positive (``S`` not positive definite, or NaN)."""
    n = S.shape[0]
    for j in range(n):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = S[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
    return True


@kernel(aot="int64(float64[:], float64[:, :], boolean)")
def estimate_status_kernel(x: np.ndarray, P: np.ndarray, definite: bool) -> int:
    """:data:`OK`, or :data:`NOT_FINITE` / :data:`NOT_PD` for the state ``x`` and covariance ``P``
    (positive definiteness tested only with ``definite``)."""
    for v in x.flat:
        if not math.isfinite(v):
            return NOT_FINITE
    for v in P.flat:
        if not math.isfinite(v):
            return NOT_FINITE
    if definite and not cholesky_kernel(P, np.zeros(P.shape)):
        return NOT_PD
    return OK


@kernel
def _product(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A B`` summed in index order (pass ``X.T`` for a transposed factor: a view, no copy)."""
    n, m = A.shape[0], B.shape[1]
    out = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[i, k] * B[k, j]
            out[i, j] = s
    return out


@kernel
def _sandwich(A: np.ndarray, P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``A P A^T + Q``, symmetrised: ``(S + S^T) / 2`` of ``S = (A P) A^T + Q`` (the products by
    :func:`_product`), in place (``S_ij + S_ji`` is ``S_ji + S_ij``)."""
    out = _product(_product(A, P), A.T)
    n = A.shape[0]
    for i in range(n):
        for j in range(i, n):
            out[i, j] = out[j, i] = 0.5 * ((out[i, j] + Q[i, j]) + (out[j, i] + Q[j, i]))
    return out


@kernel(aot="Tuple((float64[:], float64[:, :], float64, int64))(float64[:], float64[:, :], "
            "float64[:], float64[:, :], float64[:, :])")
def measurement_update_kernel(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray,
                              R: np.ndarray) -> tuple:
    """The update of the module docstring (arguments as :func:`measurement_update`: prior ``x``,
    ``P``, innovation ``nu``, Jacobian ``H``, noise ``R``): ``(x+, P+, nis, status)``; with
    :data:`INNOVATION_NOT_FINITE` or :data:`INNOVATION_NOT_PD` the other results are meaningless."""
    n, m = x.size, nu.size
    PHt = _product(P, H.T)
    S = _product(H, PHt)
    S += R
    for i in range(m):
        if not math.isfinite(nu[i]):
            return x.copy(), P.copy(), math.nan, INNOVATION_NOT_FINITE
        for j in range(m):
            if not math.isfinite(S[i, j]):
                return x.copy(), P.copy(), math.nan, INNOVATION_NOT_FINITE
    L = np.zeros((m, m))
    if not cholesky_kernel(S, L):
        return x.copy(), P.copy(), math.nan, INNOVATION_NOT_PD
    # K^T = L^-T L^-1 (P H^T)^T, column by column; z = L^-1 nu
    KT = np.empty((m, n))
    for c in range(n):
        for i in range(m):
            s = PHt[c, i]
            for k in range(i):
                s -= L[i, k] * KT[k, c]
            KT[i, c] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = KT[i, c]
            for k in range(i + 1, m):
                s -= L[k, i] * KT[k, c]
            KT[i, c] = s / L[i, i]
    z = np.empty(m)
    nis = 0.0
    for i in range(m):
        s = nu[i]
        for k in range(i):
            s -= L[i, k] * z[k]
        z[i] = s / L[i, i]
        nis += z[i] * z[i]
    if not math.isfinite(nis):          # a finite innovation far beyond its covariance
        return x.copy(), P.copy(), nis, INNOVATION_NOT_FINITE
    xf = np.empty(n)
    for i in range(n):
        s = 0.0
        for k in range(m):
            s += KT[k, i] * nu[k]
        xf[i] = x[i] + s
    # Joseph form: (I - K H) P (I - K H)^T + K R K^T
    IKH = _product(KT.T, H)
    for i in range(n):
        for j in range(n):
            IKH[i, j] = (1.0 if i == j else 0.0) - IKH[i, j]
    KRKt = _product(_product(KT.T, R), KT)
    Pf = _sandwich(IKH, P, KRKt)
    return xf, Pf, nis, estimate_status_kernel(xf, Pf, True)


@kernel(aot="Tuple((float64[:, :], int64))(float64[:, :], float64[:, :], float64[:, :], boolean)")
def time_update_kernel(F: np.ndarray, P: np.ndarray, Q: np.ndarray, definite: bool) -> tuple:
    """``(F P F^T + Q symmetrised, status)`` (the module docstring); positive definiteness
    tested only with ``definite``."""
    Pp = _sandwich(F, P, Q)
    return Pp, estimate_status_kernel(np.zeros(1), Pp, definite)


@kernel(aot="Tuple((float64[:], float64[:, :], int64))(float64[:], float64[:, :], float64[:, :], "
            "float64[:, :], float64[:], float64[:, :], boolean)")
def linear_time_update_kernel(x: np.ndarray, P: np.ndarray, F: np.ndarray, B: np.ndarray,
                              u: np.ndarray, Q: np.ndarray, definite: bool) -> tuple:
    """``(F x + B u, F P F^T + Q symmetrised, status)``; positive definiteness tested only
    with ``definite``."""
    n = x.size
    xp = np.empty(n)
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += F[i, k] * x[k]
        b = 0.0
        for k in range(u.size):
            b += B[i, k] * u[k]
        xp[i] = s + b
    Pp = _sandwich(F, P, Q)
    return xp, Pp, estimate_status_kernel(xp, Pp, definite)


# ---- the Python interface ---------------------------------------------------------------------
def raise_for(status: int, where: str, P: np.ndarray | None = None) -> None:
    """Raise the :class:`FilterDivergence` of a kernel's ``status`` (nothing for :data:`OK`),
    its message starting with ``where`` (e.g. ``"EKF diverged in the measurement update"``);
    ``P``, the covariance tested, gives the smallest eigenvalue for :data:`NOT_PD`."""
    if status == OK:
        return
    if status == INNOVATION_NOT_FINITE:
        raise FilterDivergence(f"{where}: non-finite innovation (nu, its covariance S or nu^T S^-1 nu)")
    if status == INNOVATION_NOT_PD:
        raise FilterDivergence(f"{where}: the innovation covariance is not positive definite")
    if status == NOT_FINITE:
        raise FilterDivergence(f"{where}: non-finite state or covariance")
    with np.errstate(all="ignore"):
        ev = np.linalg.eigvalsh(P).min() if P is not None else math.nan
    raise FilterDivergence(f"{where}: the covariance is not positive definite (smallest eigenvalue {ev:.3g})")


def is_positive_definite(P: np.ndarray) -> bool:
    """Whether the finite symmetric matrix ``P`` is positive definite (its Cholesky factor exists)."""
    P = np.asarray(P, float)
    return bool(cholesky_kernel(P, np.zeros(P.shape)))


def check_estimate(x: np.ndarray, P: np.ndarray, where: str, definite: bool = True) -> None:
    """Raise :class:`FilterDivergence` naming ``where`` (e.g. ``"EKF ... time update"``) unless
    ``x`` and ``P`` are finite and, with ``definite``, ``P`` is positive definite."""
    P = np.asarray(P, float)
    raise_for(estimate_status_kernel(np.asarray(x, float), P, definite), where, P)


def measurement_update(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray, R: np.ndarray,
                       where: str = "EKF diverged in the measurement update"
                       ) -> tuple[np.ndarray, np.ndarray, float]:
    """The Kalman measurement update of the module docstring.

    Parameters
    ----------
    x, P
        Prior state (n,) and covariance (n, n).
    nu
        Innovation ``y - h(x)`` (m,).
    H
        Measurement Jacobian ``dh/dx`` at ``x`` (m, n).
    R
        Measurement noise covariance (m, m).
    where
        The start of the error message.

    Returns
    -------
    x+, P+, nis
        Filtered state and covariance, and the normalised innovation squared ``nu^T S^-1 nu``.

    Raises
    ------
    FilterDivergence
        If ``nu``, ``S`` or ``nis`` is not finite, ``S`` not positive definite, ``x+`` or ``P+``
        not finite, or ``P+`` not positive definite.
    """
    xf, Pf, nis, status = measurement_update_kernel(np.asarray(x, float), np.asarray(P, float),
                                                    np.asarray(nu, float), np.asarray(H, float),
                                                    np.asarray(R, float))
    raise_for(status, where, Pf)
    return xf, Pf, nis


def time_update(F: np.ndarray, P: np.ndarray, Q: np.ndarray, where: str = "EKF diverged in the time update",
                definite: bool = True) -> np.ndarray:
    """``F P F^T + Q``, symmetrised, for the transition (Jacobian) ``F`` (n, n), the covariance
    ``P`` (n, n) and the process noise ``Q`` (n, n); ``where`` starts the error message.

    Raises
    ------
    FilterDivergence
        If the result is not finite or, with ``definite``, not positive definite.
    """
    Pp, status = time_update_kernel(np.asarray(F, float), np.asarray(P, float), np.asarray(Q, float), definite)
    raise_for(status, where, Pp)
    return Pp


def linear_time_update(x: np.ndarray, P: np.ndarray, F: np.ndarray, B: np.ndarray, u: np.ndarray,
                       Q: np.ndarray, where: str = "EKF diverged in the time update"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(F x + B u, F P F^T + Q)`` (symmetrised) for the state ``x`` (n,), its covariance ``P``,
    the input ``u`` (k,) with ``B`` (n, k), and the process noise ``Q`` (n, n); ``where`` starts
    the error message.

    Raises
    ------
    FilterDivergence
        If the result is not finite or the covariance not positive definite.
    """
    xp, Pp, status = linear_time_update_kernel(np.asarray(x, float), np.asarray(P, float), np.asarray(F, float),
                                               np.asarray(B, float), np.asarray(u, float), np.asarray(Q, float),
                                               True)
    raise_for(status, where, Pp)
    return xp, Pp


__all__ = ["FilterDivergence", "OK", "INNOVATION_NOT_PD", "NOT_FINITE", "NOT_PD", "INNOVATION_NOT_FINITE",
           "raise_for",
           "is_positive_definite", "check_estimate", "measurement_update", "time_update", "linear_time_update",
           "cholesky_kernel", "estimate_status_kernel", "measurement_update_kernel", "time_update_kernel",
           "linear_time_update_kernel"]
