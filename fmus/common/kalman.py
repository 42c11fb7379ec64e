"""Kalman-filter toolkit shared by the estimators (plain math, no FMI): the one divergence error
and the one test of an estimate (finite state, finite and positive-definite covariance).

The positive-definiteness test is a Cholesky factorisation (LAPACK ``potrf``), the test the
filters' updates themselves rely on (Joseph-form covariance, Cholesky-factored innovation
covariance: Axelsson et al. 2012, eq. 3b; Henriksson et al. 2009, eq. 4b).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dpotrf


class FilterDivergence(FloatingPointError):
    """The estimate became non-finite or its covariance lost positive definiteness; an estimator
    FMU ends the step with an FMI error naming the cause and holds its last good estimate
    (:class:`fmus.common.filter_adapter.FilterAdapter`)."""


def is_positive_definite(P: np.ndarray) -> bool:
    """Whether the finite symmetric matrix ``P`` is positive definite (its Cholesky factor exists)."""
    return dpotrf(P, lower=1, clean=0)[1] == 0


def check_estimate(x: np.ndarray, P: np.ndarray, where: str, definite: bool = True) -> None:
    """Raise :class:`FilterDivergence` naming ``where`` (e.g. ``"EKF ... time update"``) unless
    ``x`` and ``P`` are finite and, with ``definite``, ``P`` is positive definite."""
    if not (math.isfinite(float(np.sum(x))) and math.isfinite(float(np.sum(P)))):
        raise FilterDivergence(f"{where}: non-finite state or covariance")
    if definite and not is_positive_definite(P):
        with np.errstate(all="ignore"):
            ev = np.linalg.eigvalsh(P).min()
        raise FilterDivergence(f"{where}: the covariance is not positive definite "
                               f"(smallest eigenvalue {ev:.3g})")


__all__ = ["FilterDivergence", "is_positive_definite", "check_estimate"]
