"""The measurement model of Axelsson, Karlsson and Norrlöf (2012), eqs. 11 and 15-19, for many
states at once: the particles of the particle filter
(:mod:`fmus.estimators.particle_filter_model`) and the runs of the Cramér-Rao bound
(:mod:`orchestration.crlb`).

There is one model: the scalar kernels of :mod:`fmus.estimators.axelsson2012_model` (the EKF's
:meth:`~fmus.estimators.axelsson2012_model.MeasurementModel.h_and_jacobian`), with their
constants vector and indices. :func:`measure_many` loops over the rows of the states ``X``
(N, n) and calls :func:`~fmus.estimators.axelsson2012_model.measure_into` on each, so each row's
numbers are the scalar model's, bit for bit, by construction. The particle filter's speed-ups
are arguments of the scalar spring solve
(:func:`~fmus.estimators.axelsson2012_model.spring_deflection_kernel`): Newton warm-started from
the deflections the particles had before their move, and stopped as soon as Newton's error
bound says the tolerance is met (the same root within the same tolerance).
"""
from __future__ import annotations

import numpy as np

from fmus.common.jit import kernel
from fmus.estimators.axelsson2012_model import MeasurementModel, measure_into


@kernel
def measure_many(X, k, use_accelerometer, use_bias, bound_stop, D0, Y, H, D):
    """``h(x)`` (eq. 15) into ``Y`` (N, m) and, if ``H`` has rows, ``H = dh/dx`` (eq. 4c) into
    ``H`` (N, m, n) (zero outside the entries written here: the caller's), for the rows of
    ``X`` (N, n); the gearbox deflections into ``D`` (N, 2, may be ``D0`` itself).

    ``k``, ``use_accelerometer``, ``use_bias``: the scalar model's
    (:attr:`~fmus.estimators.axelsson2012_model.MeasurementModel.constants` and ``switches``);
    Newton starts from ``D0`` (N, 2; NaN: cold) with ``bound_stop``
    (:func:`~fmus.estimators.axelsson2012_model.spring_deflection_kernel`). Each row is
    :func:`~fmus.estimators.axelsson2012_model.measure_into`.
    """
    for i in range(X.shape[0]):
        D[i, 0], D[i, 1] = measure_into(X[i], k, use_accelerometer, use_bias, D0[i, 0], D0[i, 1], bound_stop,
                                        Y[i], H[i])


class BatchedMeasurement:
    """``h(x)`` of eq. 15 and its Jacobian for the rows of ``X`` (N, n): particles or runs.

    Parameters
    ----------
    meas
        The scalar :class:`~fmus.estimators.axelsson2012_model.MeasurementModel` whose robot
        model, constants and state layout this one uses: each row's numbers are its
        ``h_and_jacobian``'s, bit for bit.
    """

    def __init__(self, meas: MeasurementModel) -> None:
        self.meas = meas
        self.layout = meas.layout

    def _evaluate(self, X: np.ndarray, jacobian: bool):
        X = np.ascontiguousarray(X, dtype=float)
        N, L = X.shape[0], self.layout
        Y, D = np.empty((N, L.m)), np.full((N, 2), np.nan)      # D: Newton starts cold
        H = np.zeros((N, L.m, L.n) if jacobian else (N, 0, 0))
        measure_many(X, self.meas.constants, *self.meas.switches, False, D, Y, H, D)
        return Y, H, D

    def h(self, X: np.ndarray) -> np.ndarray:
        """``h(x)`` (N, m) for the rows of ``X`` (N, n)."""
        return self._evaluate(X, False)[0]

    def h_and_jacobian(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``h(x)`` (N, m) and ``H = dh/dx`` (N, m, n) for the rows of ``X`` (N, n)."""
        Y, H, _ = self._evaluate(X, True)
        return Y, H

    def deflection(self, X: np.ndarray) -> np.ndarray:
        """The gearbox deflections ``D = tau_s^{-1}(tau_a)`` (eq. 16), (N, 2), of the rows of
        ``X`` (N, n)."""
        return self._evaluate(X, False)[2]


__all__ = ["BatchedMeasurement", "measure_many"]
