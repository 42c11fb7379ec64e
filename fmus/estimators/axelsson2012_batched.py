"""The measurement model of Axelsson, Karlsson and Norrlöf (2012), eqs. 11 and 15-19, for many
states at once: the particles of the particle filter
(:mod:`fmus.estimators.particle_filter_model`) and the runs of the Cramér-Rao bound
(:mod:`orchestration.crlb`).

There is one model: the scalar kernels of :mod:`fmus.estimators.axelsson2012_model` (those of
the EKF's :meth:`~fmus.estimators.axelsson2012_model.MeasurementModel.h_and_jacobian`), with
their constants vector and indices. :func:`measure_many` runs them over the rows of the states
``X`` (N, n) in the scalar ``measurement_kernel``'s sequence, so each row's numbers are the
scalar model's, bit for bit, by construction (tested): a row's motion and torque, the spring's
inverse, ``h_into`` and ``jacobian_into``. Two things are arranged for speed, not for other
numbers: the rows' Newton steps on the spring are interleaved (:func:`deflections`: one
``spring_newton_step`` per row and sweep), and each layout of the state gets its own compiled
loop. The particle filter's speed-ups are arguments of the scalar spring solve
(:func:`~fmus.estimators.axelsson2012_model.spring_deflection_kernel`): Newton warm-started from
the deflections the particles had before their move (``D0``), and stopped as soon as Newton's
error bound says the tolerance is met (``bound_stop``: the same root within the same
tolerance).
"""
from __future__ import annotations

import numpy as np

from fmus.common.jit import kernel
from fmus.estimators.axelsson2012_model import (K_DELTA, K_KHI, K_KSOFT, NEWTON_STEPS, MeasurementModel,
                                                arm_torque_kernel, h_into, jacobian_into, motion,
                                                spring_newton_step, spring_start)


@kernel
def deflections(tau, k_hi, k_soft, delta, D0, bound_stop, D):
    """The gearbox deflections ``D`` (N,) of one joint (its spring's ``k_hi``, ``k_soft`` and
    ``delta``) carrying the torques ``tau`` (N,):
    :func:`~fmus.estimators.axelsson2012_model.spring_deflection_kernel` for each, from ``D0``
    (N,; NaN: cold; may be ``D`` itself) with ``bound_stop``, the rows' Newton steps
    interleaved (a sweep over the rows per step: independent chains of ``tanh``, where one
    row's Newton is a chain of dependent ones; each row's steps and numbers are the scalar
    solve's)."""
    N = tau.shape[0]
    done = np.zeros(N, np.bool_)
    for i in range(N):
        D[i] = spring_start(tau[i], k_hi, k_soft, delta, D0[i])
    for _ in range(NEWTON_STEPS):
        left = False
        for i in range(N):
            if not done[i]:
                D[i], done[i] = spring_newton_step(D[i], tau[i], k_hi, k_soft, delta, bound_stop)
                left = left or not done[i]
        if not left:
            break


@kernel(inline="always")
def _rows(X, S, D, k, use_accelerometer, use_bias, Y, H):
    """:func:`measure_many`'s last pass: ``h_into`` and ``jacobian_into`` for each row."""
    for i in range(X.shape[0]):
        h_into(X[i], S[i], k, use_accelerometer, use_bias, D[i, 0], D[i, 1], Y[i])
    if H is not None:
        for i in range(X.shape[0]):
            jacobian_into(S[i], k, use_accelerometer, use_bias, D[i, 0], D[i, 1], H[i])


@kernel(aot="none(float64[:, :], float64[:], boolean, boolean, boolean, float64[:, :], "
            "float64[:, :], float64[:, :, :], float64[:, :])")
def measure_many(X, k, use_accelerometer, use_bias, bound_stop, D0, Y, H, D):
    """``h(x)`` (eq. 15) into ``Y`` (N, m) and, unless ``H`` is None, ``H = dh/dx`` (eq. 4c)
    into ``H`` (N, m, n) (zero outside the entries written here: the caller's), for the rows of
    ``X`` (N, n); the gearbox deflections into ``D`` (N, 2, may be ``D0`` itself).

    ``k``, ``use_accelerometer``, ``use_bias``: the scalar model's
    (:attr:`~fmus.estimators.axelsson2012_model.MeasurementModel.constants` and ``switches``);
    Newton starts from ``D0`` (N, 2; NaN: cold) with ``bound_stop`` (:func:`deflections`). Each
    row is ``measurement_kernel``'s sequence of kernels: the arm torque, the spring's inverse
    (here over all rows at once, :func:`deflections`), ``h_into`` and ``jacobian_into``.
    """
    N, n = X.shape
    m = 4 if use_accelerometer else 2
    if Y.shape != (N, m) or D.shape != (N, 2) or D0.shape != (N, 2) or n < 6 + 2 * use_bias + 2 * (
            use_bias and use_accelerometer) or H is not None and H.shape != (N, m, n):
        raise ValueError("measure_many: the shapes of Y (N, m), H (N, m, n) or None, D and D0 (N, 2) "
                         "do not fit X (N, n) and the layout")  # the kernels do not check indices
    S = np.empty((N, 11))            # the rows' motions (their sines and cosines computed once)
    tau = np.empty((2, N))
    for i in range(N):
        s = motion(X[i])
        for j in range(11):
            S[i, j] = s[j]
        tau[0, i], tau[1, i] = arm_torque_kernel(s, k)
    for j in range(2):
        deflections(tau[j], k[K_KHI + j], k[K_KSOFT + j], k[K_DELTA + j], D0[:, j], bound_stop, D[:, j])
    # each layout its own loop, the switches constants in it (about 10 ns a row less)
    if use_accelerometer and use_bias:
        _rows(X, S, D, k, True, True, Y, H)
    elif use_accelerometer:
        _rows(X, S, D, k, True, False, Y, H)
    elif use_bias:
        _rows(X, S, D, k, False, True, Y, H)
    else:
        _rows(X, S, D, k, False, False, Y, H)


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
        H = np.zeros((N, L.m, L.n))        # also without ``jacobian``: one type, measure_many's aot=
        measure_many(X, self.meas.constants, *self.meas.switches, False, D, Y, H, D)
        return Y, H if jacobian else None, D

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


__all__ = ["BatchedMeasurement", "measure_many", "deflections"]
