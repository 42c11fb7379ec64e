"""The extended Kalman filter of Axelsson, Karlsson and Norrlöf (2012): arm angles from the motor
angles and a tool accelerometer.

The estimation model (state, eqs. 12-14; measurements, eqs. 15-19; noise, eq. 26) is in
:mod:`fmus.estimators.axelsson2012_model`; this module is the filter (eq. 3).
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common import kinematics
from fmus.common.kalman import FilterDivergence, check_estimate, cholesky_lower, solve
from fmus.estimators.axelsson2012_model import (Q_, EkfAccelerometerParameters, Layout, MeasurementModel,
                                                initial_covariance, measurement_noise, process_noise,
                                                transition_matrices)


# ---- the filter (eq. 3) --------------------------------------------------------------------
class EkfAccelerometerModel:
    """The EKF of eq. 3 with the model of eqs. 12-19.

    Parameters
    ----------
    p
        Filter parameters (its robot model, noise, initial estimate, switches).

    Notes
    -----
    Per sample: :meth:`update` with the measurement ``y_t`` gives ``x_{t|t}`` (eq. 3b, Joseph
    form), then :meth:`predict` with the jerk reference ``u_t`` gives ``x_{t+1|t}`` (eq. 3a).
    :meth:`filtered` computes the update without committing it (for an FMU's outputs).
    """

    def __init__(self, p: EkfAccelerometerParameters) -> None:
        self.p = p
        self.layout = Layout(bool(p.use_accelerometer), bool(p.use_bias))
        self.meas = MeasurementModel(p.robot(), self.layout)
        self.Q = process_noise(p, self.layout)
        self.R = measurement_noise(p, self.layout)
        self.x = np.zeros(self.layout.n)
        self.x[Q_] = p.initial_angles()
        self.P = initial_covariance(p, self.layout)
        self._T: float | None = None
        self._I = np.eye(self.layout.n)
        self.innovation_norm = 0.0

    def _matrices(self, T: float) -> None:
        if self._T != T:
            self.F, self.Gu, Gw = transition_matrices(T, self.layout)
            self.GQG = Gw @ self.Q @ Gw.T
            self._T = T

    def measurement_vector(self, q_m, acc_xz=None) -> np.ndarray:
        """``y`` of eq. 15 from the motor angles ``q_m`` (rad) and, if the filter uses it, the
        accelerometer's ``acc_xz`` (m/s^2): :meth:`Layout.measurement_vector`."""
        return self.layout.measurement_vector(q_m, acc_xz)

    def filtered(self, y, x=None, P=None) -> tuple[np.ndarray, np.ndarray, float]:
        """``(x_{t|t}, P_{t|t}, normalised innovation norm)`` for the measurement ``y`` (eq. 3b)
        from the prior ``x, P`` (default: the filter's own), without committing it.

        Raises
        ------
        FilterDivergence
            If the result is non-finite or its covariance not positive definite.
        """
        x = self.x if x is None else x
        P = self.P if P is None else P
        with np.errstate(all="ignore"):      # non-finite results are caught by check_estimate
            return self._filtered(np.asarray(y, float), x, P)

    def _filtered(self, y: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        hx, H = self.meas.h_and_jacobian(x)
        nu = y - hx
        S = H @ P @ H.T + self.R
        Sc = cholesky_lower(S)
        if Sc is None:
            raise FilterDivergence("EKF diverged in the measurement update: the innovation covariance "
                                   "is not positive definite")
        PHt = P @ H.T
        K = solve(Sc.T, solve(Sc, PHt.T)).T
        xf = x + K @ nu
        IKH = self._I - K @ H
        Pf = IKH @ P @ IKH.T + K @ self.R @ K.T      # Joseph form of P - K H P
        Pf = 0.5 * (Pf + Pf.T)
        z = solve(Sc, nu)
        check_estimate(xf, Pf, "EKF diverged in the measurement update")
        return xf, Pf, float(math.sqrt(z @ z))

    def update(self, y) -> np.ndarray:
        """Measurement update (eq. 3b) with the measurement ``y`` (eq. 15, as stacked by
        :meth:`measurement_vector`); commits and returns ``x_{t|t}``."""
        self.x, self.P, self.innovation_norm = self.filtered(y)
        return self.x

    def predict(self, u, T: float) -> np.ndarray:
        """Time update over the period ``T`` [s] with the arm jerk reference ``u`` (2,) [rad/s^3]
        held (eqs. 3a, 13); commits and returns ``x_{t+1|t}``."""
        self.x, self.P = self.predicted(u, T)
        return self.x

    def predicted(self, u, T: float, x=None, P=None) -> tuple[np.ndarray, np.ndarray]:
        """``(x, P)`` predicted over ``T`` from ``x, P`` (default: the filter's own) with the
        jerk reference ``u`` held (eqs. 3a, 13), without committing it."""
        x = self.x if x is None else x
        P = self.P if P is None else P
        self._matrices(float(T))
        with np.errstate(all="ignore"):      # non-finite results are caught by check_estimate
            x = self.F @ x + self.Gu @ np.asarray(u, float)
            P = self.F @ P @ self.F.T + self.GQG
            P = 0.5 * (P + P.T)
        check_estimate(x, P, "EKF diverged in the time update")
        return x, P

    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) [m] from the arm angles of the state ``x`` (default: the
        filter's estimate) by the rigid forward kinematics (eq. 29)."""
        return kinematics.tool_position((self.x if x is None else x)[Q_], self.meas.p)


__all__ = ["EkfAccelerometerModel"]
