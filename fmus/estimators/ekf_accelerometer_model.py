"""The extended Kalman filter of Axelsson, Karlsson and Norrlöf (2012): arm angles from the motor
angles and a tool accelerometer.

The estimation model (state, eqs. 12-14; measurements, eqs. 15-19; noise, eq. 26) is in
:mod:`fmus.estimators.axelsson2012_model`; this module is the filter (eq. 3).
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common import kinematics
from fmus.common.jit import kernel
from fmus.common.kalman import FilterDivergence, linear_time_update, measurement_update_kernel, raise_for
from fmus.estimators.axelsson2012_model import (Q_, EkfAccelerometerParameters, Layout, MeasurementModel,
                                                initial_covariance, measurement_kernel, measurement_noise,
                                                process_noise, transition_matrices)


# ---- the filter (eq. 3), compiled ---------------------------------------------------------
@kernel(aot="Tuple((float64[:], float64[:, :], float64, int64))(float64[:], float64[:, :], "
            "float64[:], float64[:, :], float64[:], boolean, boolean)")
def filtered_kernel(x: np.ndarray, P: np.ndarray, y: np.ndarray, R: np.ndarray, k: np.ndarray,
                    use_accelerometer: bool, use_bias: bool) -> tuple:
    """Eq. 3b at the prior ``x, P`` for the measurement ``y`` with the noise ``R``: the model's
    linearisation (:func:`~fmus.estimators.axelsson2012_model.measurement_kernel`, constants
    ``k``, switches ``use_accelerometer`` and ``use_bias``) and the shared update
    (:func:`fmus.common.kalman.measurement_update_kernel`): ``(x+, P+, nis, status)``."""
    hx, H = measurement_kernel(x, k, use_accelerometer, use_bias)
    return measurement_update_kernel(x, P, y - hx, H, R)


class EkfAccelerometerModel:
    """The EKF of eq. 3 with the model of eqs. 12-19.

    Parameters
    ----------
    p
        Filter parameters (its robot model, noise, initial estimate, switches).

    Notes
    -----
    Per sample: :meth:`update` with the measurement ``y_t`` gives ``x_{t|t}`` (eq. 3b, the
    Joseph form of :mod:`fmus.common.kalman`), then :meth:`predict` with the jerk reference
    ``u_t`` gives ``x_{t+1|t}`` (eq. 3a). :meth:`filtered` computes the update without
    committing it (for an FMU's outputs). Both are compiled kernels.
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
            If the innovation covariance or the result's covariance is not positive definite,
            or the result is not finite.
        """
        x = self.x if x is None else x
        P = self.P if P is None else P
        xf, Pf, nis, status = filtered_kernel(np.asarray(x, float), np.asarray(P, float), np.asarray(y, float),
                                              self.R, self.meas.constants, *self.meas.switches)
        raise_for(status, "EKF diverged in the measurement update", Pf)
        return xf, Pf, math.sqrt(nis)

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
        self._matrices(float(T))
        return linear_time_update(self.x if x is None else x, self.P if P is None else P,
                                  self.F, self.Gu, u, self.GQG)

    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) [m] from the arm angles of the state ``x`` (default: the
        filter's estimate) by the rigid forward kinematics (eq. 29)."""
        return kinematics.tool_position((self.x if x is None else x)[Q_], self.meas.p)


__all__ = ["EkfAccelerometerModel", "FilterDivergence", "filtered_kernel"]
