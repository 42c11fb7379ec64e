"""Kalman-filter toolkit shared by the estimators (plain math, no FMI): the one divergence error
and the one test of an estimate (finite state, finite and positive-definite covariance).

The positive-definiteness test is a Cholesky factorisation (LAPACK ``potrf``), the test the
filters' updates themselves rely on (Joseph-form covariance, Cholesky-factored innovation
covariance: Axelsson et al. 2012, eq. 3b; Henriksson et al. 2009, eq. 4b).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.linalg import _umath_linalg
from scipy.linalg.lapack import dpotrf


class FilterDivergence(FloatingPointError):
    """The estimate became non-finite or its covariance lost positive definiteness; an estimator
    FMU ends the step with an FMI error naming the cause and holds its last good estimate
    (:class:`fmus.common.filter_adapter.FilterAdapter`)."""


def is_positive_definite(P: np.ndarray) -> bool:
    """Whether the finite symmetric matrix ``P`` is positive definite (its Cholesky factor exists)."""
    return dpotrf(P, lower=1, clean=0)[1] == 0


# The gufuncs behind np.linalg.cholesky and np.linalg.solve, called directly: the same LAPACK
# routines and the same bits, without the wrappers' type checks and error-state handling (about
# 6 us a call, more than the arithmetic on the filters' 4x4 and 6x6 matrices).
def cholesky_lower(S: np.ndarray) -> np.ndarray | None:
    """The lower Cholesky factor of the float64 matrix ``S`` (as ``np.linalg.cholesky``), or
    None where that raises (``S`` not positive definite)."""
    try:
        with np.errstate(invalid="raise"):  # how the gufunc reports a failed factorisation
            return _umath_linalg.cholesky_lo(S, signature="d->d")
    except FloatingPointError:
        return None


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` for float64 ``A`` and a vector or matrix ``b`` (as ``np.linalg.solve``)."""
    return _umath_linalg.solve1(A, b, signature="dd->d") if b.ndim == 1 else \
        _umath_linalg.solve(A, b, signature="dd->d")


def check_estimate(x: np.ndarray, P: np.ndarray, where: str, definite: bool = True) -> None:
    """Raise :class:`FilterDivergence` naming ``where`` (e.g. ``"EKF ... time update"``) unless
    ``x`` and ``P`` are finite and, with ``definite``, ``P`` is positive definite."""
    if not (math.isfinite(x.sum()) and math.isfinite(P.sum())):
        raise FilterDivergence(f"{where}: non-finite state or covariance")
    if definite and not is_positive_definite(P):
        with np.errstate(all="ignore"):
            ev = np.linalg.eigvalsh(P).min()
        raise FilterDivergence(f"{where}: the covariance is not positive definite "
                               f"(smallest eigenvalue {ev:.3g})")


__all__ = ["FilterDivergence", "is_positive_definite", "check_estimate", "cholesky_lower", "solve"]
