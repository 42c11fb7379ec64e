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
from fmus.common.kalman import (OK, FilterDivergence, linear_time_update, linear_time_update_kernel,
                                measurement_update_kernel, raise_for)
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


# ---- one fusion in one call (the FMU's step) -------------------------------------------------
#: Where :func:`fusion_step_kernel` stopped on a divergence (its second result).
TIME_UPDATE, MEASUREMENT_UPDATE = 0, 1
#: The outputs :func:`fusion_step_kernel` writes, in this order: ``x[0:6]`` (arm angles,
#: velocities, accelerations), the tool position (2) and the lower triangle of the covariance
#: of ``x[0:6]`` row by row (21, ``numpy.tril_indices(6)``).
SHOWN_SIZE = 6 + 2 + 21


def packed_estimate(x: np.ndarray, P: np.ndarray, innovation_norm: float, u: np.ndarray) -> np.ndarray:
    """An estimate as :func:`fusion_step_kernel` takes it, one array: the state ``x`` (n),
    its covariance ``P`` row by row (n * n), the normalised innovation norm of its last update
    ``innovation_norm`` and the jerk reference ``u`` (2) at its time."""
    return np.concatenate([np.asarray(x, float), np.ravel(P), [float(innovation_norm)], np.asarray(u, float)])


def packed_covariance(e: np.ndarray, n: int) -> np.ndarray:
    """The covariance (n, n) in the packed estimate ``e`` (:func:`packed_estimate`) of ``n`` states."""
    return e[n:n + n * n].reshape(n, n)


@kernel
def _carried(x: np.ndarray, P: np.ndarray, u0: np.ndarray, u: np.ndarray, n: int, F: np.ndarray,
             Gu: np.ndarray, GQG: np.ndarray) -> tuple:
    """``(x, P, status)`` carried over ``n`` sample periods (eqs. 3a, 13: ``F``, ``G_u`` and
    ``G_w Q G_w^T`` of the period) with the jerk reference the mean of ``u0`` (at the start)
    and ``u`` (at the end), then ``u`` (each period of a longer interval)."""
    status = OK
    for _ in range(n):
        x, P, status = linear_time_update_kernel(x, P, F, Gu, 0.5 * (u0 + u), GQG, True)
        if status != OK:
            break
        u0 = u
    return x, P, status


@kernel
def _pack_into(x: np.ndarray, P: np.ndarray, norm: float, u: np.ndarray, e: np.ndarray) -> None:
    """Write the estimate into ``e`` (:func:`packed_estimate`)."""
    n = x.size
    for i in range(n):
        e[i] = x[i]
        for j in range(n):
            e[n + i * n + j] = P[i, j]
    e[n + n * n] = norm
    e[n + n * n + 1], e[n + n * n + 2] = u[0], u[1]


@kernel(aot="Tuple((int64, int64, float64, float64))(float64[:], float64[:], int64, float64[:, :], "
            "float64[:, :], float64[:, :], boolean, float64[:], float64[:], int64, float64[:, :], float64[:, :], "
            "float64[:, :], float64[:], float64[:], int64, int64, int64, float64[:, :], float64[:], boolean, boolean, "
            "float64, float64)")
def fusion_step_kernel(e: np.ndarray, u: np.ndarray, n: int, F: np.ndarray, Gu: np.ndarray, GQG: np.ndarray,
                       fuse: bool, q_m: np.ndarray, acc: np.ndarray, n_show: int, F_show: np.ndarray,
                       Gu_show: np.ndarray, GQG_show: np.ndarray, out: np.ndarray, outputs: np.ndarray, first: int,
                       ix: int, iz: int, R: np.ndarray, k: np.ndarray, use_accelerometer: bool, use_bias: bool,
                       l1: float, l2: float) -> tuple:
    """One fusion of the filter in one call: the estimate ``e`` (:func:`packed_estimate`)
    carried over ``n`` sample periods (eqs. 3a, 13, the matrices ``F``, ``Gu``, ``GQG`` of
    :meth:`EkfAccelerometerModel.transition`; the jerk reference the mean of the estimate's
    and ``u``, then ``u``) and, with ``fuse``, updated (eq. 3b, :func:`filtered_kernel`) with the
    motor angles ``q_m`` and the accelerometer's ``acc[ix]``, ``acc[iz]`` (eq. 15), into
    ``out``; then that estimate carried ``n_show`` periods further (``F_show``, ``Gu_show``,
    ``GQG_show``) and shown: :data:`SHOWN_SIZE` outputs from ``outputs[first]`` on, the tool
    position by the rigid forward kinematics (eq. 29) of the links ``l1``, ``l2``. ``R``,
    ``k``, ``use_accelerometer``, ``use_bias`` as for :func:`filtered_kernel`.

    The arithmetic is the separate calls' (:meth:`EkfAccelerometerModel.predicted`,
    :meth:`~EkfAccelerometerModel.filtered`), bit for bit. Returns ``(status, stage, trace of
    the shown covariance of q_a, its innovation norm)``; on a divergence (``status`` not
    :data:`~fmus.common.kalman.OK`, ``stage`` :data:`TIME_UPDATE` or
    :data:`MEASUREMENT_UPDATE`) ``out`` holds the estimate that failed and no output is written.
    """
    N = F.shape[0]
    x, P = np.empty(N), np.empty((N, N))
    for i in range(N):
        x[i] = e[i]
        for j in range(N):
            P[i, j] = e[N + i * N + j]
    norm, u_e = e[N + N * N], e[N + N * N + 1:N + N * N + 3].copy()
    x, P, status = _carried(x, P, u_e, u, n, F, Gu, GQG)
    if n > 0:
        u_e = u.copy()
    if status == OK and fuse:
        m = 4 if use_accelerometer else 2
        y = np.empty(m)
        y[0], y[1] = q_m[0], q_m[1]
        if use_accelerometer:
            y[2], y[3] = acc[ix], acc[iz]
        x, P, nis, status = filtered_kernel(x, P, y, R, k, use_accelerometer, use_bias)
        if status != OK:
            _pack_into(x, P, norm, u_e, out)
            return status, MEASUREMENT_UPDATE, math.nan, math.nan
        norm = math.sqrt(nis)
    _pack_into(x, P, norm, u_e, out)
    if status != OK:
        return status, TIME_UPDATE, math.nan, math.nan
    x, P, status = _carried(x, P, u_e, u, n_show, F_show, Gu_show, GQG_show)
    if status != OK:
        _pack_into(x, P, norm, u, out)
        return status, TIME_UPDATE, math.nan, math.nan
    for i in range(6):
        outputs[first + i] = x[i]
    outputs[first + 6], outputs[first + 7] = kinematics.tool_point(x[0], x[1], l1, l2)
    c = first + 8
    for i in range(6):
        for j in range(i + 1):
            outputs[c] = P[i, j]
            c += 1
    return OK, TIME_UPDATE, P[0, 0] + P[1, 1], norm


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
    ``u_t`` gives ``x_{t+1|t}`` (eq. 3a). :meth:`filtered` and :meth:`predicted` compute them
    without committing (the batched engine's per-run filter). All are compiled kernels; the FMU
    runs both and its outputs in one call (:func:`fusion_step_kernel`).
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
        self._transitions: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.innovation_norm = 0.0

    def transition(self, T: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(F, G_u, G_w Q G_w^T)`` of the sample period ``T`` [s] (eqs. 13-14, 26), kept
        for the few periods a run meets."""
        mats = self._transitions.get(T)
        if mats is None:
            F, Gu, Gw = transition_matrices(T, self.layout)
            mats = (F, Gu, Gw @ self.Q @ Gw.T)
            if len(self._transitions) >= 16:      # bounded whatever the host's steps
                self._transitions.clear()
            self._transitions[T] = mats
        return mats

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
        F, Gu, GQG = self.transition(float(T))
        return linear_time_update(self.x if x is None else x, self.P if P is None else P, F, Gu, u, GQG)

    def tool_position(self, x=None) -> np.ndarray:
        """Tool position (world x, z) [m] from the arm angles of the state ``x`` (default: the
        filter's estimate) by the rigid forward kinematics (eq. 29)."""
        return kinematics.tool_position((self.x if x is None else x)[Q_], self.meas.p)


__all__ = ["EkfAccelerometerModel", "FilterDivergence", "filtered_kernel", "fusion_step_kernel", "packed_estimate",
           "packed_covariance", "SHOWN_SIZE", "TIME_UPDATE", "MEASUREMENT_UPDATE"]
