"""The measurement model of Axelsson, Karlsson and Norrlöf (2012), eqs. 11 and 15-19, for many
states at once: the particles of the particle filter
(:mod:`fmus.estimators.particle_filter_model`) and the runs of the batched study engine
(:mod:`fmus.estimators.ekf_accelerometer_batched`) evaluate it with the same compiled code.

Each row of the states ``X`` (N, n) goes through :func:`measure_many`, a ``@kernel``
(:mod:`fmus.common.jit`) that repeats the scalar model
(:meth:`fmus.estimators.axelsson2012_model.MeasurementModel.h_and_jacobian`) expression by
expression, in the same order and with the same library calls: ``math.sin``, ``math.cos`` and
``math.tanh`` are libm's, as in Python, and with ``exact`` ``tanh(D / delta) ** 2`` is C's
``pow`` (Python's ``**``), which is not always the correctly rounded square ``t * t`` (in
about 1 of 1200 draws here): the exponent :data:`POW_EXPONENT` is read from the constants
vector at run time, so that the compiler cannot fold ``pow(t, 2)`` into ``t * t``. So each
row's numbers are the scalar model's bit for bit (tested), and a batched run is its single
filter. Without ``exact`` (the particle filter, which has no scalar twin) the square is
``t * t`` (one ``pow`` less per Newton step on the critical path of the iteration: 235 -> 143
ns per deflection, measured on a loaded machine) and the iteration stops as soon as Newton's error bound says the
tolerance is met (:func:`deflections`): the same root within the same tolerance.

The model (the scalar one's docstring has the details): arm torque ``tau_a = M(q) ddq + C(q, dq)
dq + G(q)`` (eq. 11), gearbox deflection ``D = tau_s^{-1}(tau_a)`` by Newton's method on
``tau_s(D) = k_hi D - (k_hi - k_lo) delta tanh(D / delta)`` (eq. 16 with the nonlinear spring of
:func:`fmus.common.dynamics.spring_deflection`), motor angles ``r (q + D) + b_m`` (eq. 16),
specific force at the accelerometer (eqs. 17-19) ``+ b_acc``, and the analytic Jacobian
``H = dh/dx`` (eq. 4c).
"""
from __future__ import annotations

import math

import numpy as np

from fmus.common.jit import kernel
from fmus.estimators.axelsson2012_model import Layout, MeasurementModel

#: The exponent of ``tanh(D / delta) ** 2``, in the kernels' constants vector (not a constant
#: in their code) so that it stays a call of C's ``pow``, as Python's ``**`` is (module docstring).
POW_EXPONENT = 2.0

# indices into the constants vector of :func:`model_constants`
_A, _C, _E, _G1, _G2, _G, _L1, _V0, _V1, _SV0, _SV1, _R0, _R1 = range(13)
_K_HI, _K_SOFT, _DELTA = 13, 15, 17          # two joints each
_TWO = 19


def model_constants(meas: MeasurementModel) -> np.ndarray:
    """The constants of the scalar model ``meas`` that the kernels use, as one vector (20,):
    the inertia, Coriolis and gravity constants (eq. 11), ``g``, ``l1``, the mount ``v`` and
    ``S v`` (eqs. 17-19), the gear ratios (eq. 16) and the spring's ``k_hi``, ``k_hi - k_lo``
    and ``delta`` per joint (the very floats the scalar model computes with); then
    :data:`POW_EXPONENT`."""
    return np.array([meas.a, meas.c, meas.e, meas.g1, meas.g2, meas.g, meas.l1, *meas.v, *meas.Sv,
                     *meas.r, *meas._k_hi, *meas._k_soft, *meas._delta, POW_EXPONENT], float)


def layout_offsets(layout: Layout) -> tuple[int, int, int]:
    """The layout as the kernels take it: the number of measurements ``m`` and the first index
    of the motor-angle and accelerometer biases in the state (-1: none), for ``layout``."""
    return (layout.m, -1 if layout.bias_m is None else layout.bias_m.start,
            -1 if layout.bias_acc is None else layout.bias_acc.start)


#: ``max |d^2/dx^2 tanh(x)| / 2 = 2 / (3 sqrt(3))``: bounds Newton's next residual (:func:`deflections`)
_HALF_MAX_TANH2 = 2.0 / (3.0 * math.sqrt(3.0))


@kernel
def _newton_step(d, tau, k_hi, k_soft, delta, tol, two, exact):
    """One Newton step of ``tau_s(d) = tau``: ``(d_next, done)`` (:func:`deflections`)."""
    t = math.tanh(d / delta)
    f = k_hi * d - k_soft * delta * t - tau
    k = k_hi - k_soft * (1.0 - (t ** two if exact else t * t))
    d -= f / k
    if abs(f) <= tol:
        return d, True
    # |tau_s(d_next) - tau| <= max|tau_s''| / 2 (f / k)^2, tau_s'' = -(k_soft / delta) tanh''
    return d, not exact and _HALF_MAX_TANH2 * k_soft / delta * (f / k) * (f / k) <= tol


@kernel
def deflections(tau, k_hi, k_soft, delta, two, exact, D0, D):
    """The gearbox deflections ``D`` (N,) of one joint with ``tau_s(D_i) = tau_i`` for the arm
    torques ``tau`` (N,) (eq. 16's spring: ``k_hi``, ``k_soft = k_hi - k_lo``, ``delta``), by
    Newton's method from ``D0`` (N,; NaN: from the high-stiffness asymptote shifted by the soft
    zone) to the residual
    ``|tau_s(D_i) - tau_i| <= 1e-12 max(1, |tau_i|)`` (at most 50 steps). The rows' iterations
    are interleaved (a sweep over the rows per step: independent chains of ``tanh``, where one
    row's Newton is a chain of dependent ones).

    With ``exact``, each row in the scalar model's order and rounding: step, then stop once the
    residual before the step is within the tolerance; ``tanh`` squared with C's ``pow`` and the
    exponent ``two`` (:data:`POW_EXPONENT`, read at run time). Without (faster; the same root
    within the tolerance): squares as ``t * t``, and stop already when Newton's bound on the
    next residual, ``max|tau_s''| / 2 (f / k)^2`` with ``max|tau_s''| = 4 / (3 sqrt 3)
    k_soft / delta``, is within the tolerance (one ``tanh`` less per row and joint).
    """
    N = tau.shape[0]
    done = np.zeros(N, np.bool_)
    for i in range(N):
        t = tau[i]
        D[i] = ((t + math.copysign(k_soft * delta * math.tanh(abs(t) / (k_hi * delta)), t)) / k_hi
                if math.isnan(D0[i]) else D0[i])
    for _ in range(50):
        left = False
        for i in range(N):
            if not done[i]:
                D[i], done[i] = _newton_step(D[i], tau[i], k_hi, k_soft, delta,
                                             1e-12 * max(1.0, abs(tau[i])), two, exact)
                left = left or not done[i]
        if not left:
            break


@kernel
def measure_many(X, c, m, bias_m, bias_acc, exact, D0, Y, H, D):
    """``h(x)`` (eq. 15) into ``Y`` (N, m) and, if ``H`` has rows, ``H = dh/dx`` (eq. 4c) into
    ``H`` (N, m, n) (zero outside the entries written here), for the rows of ``X`` (N, n); the
    deflections into ``D`` (N, 2), Newton from ``D0`` (N, 2; NaN: cold, :func:`deflections`).

    ``c``: :func:`model_constants`; ``m``, ``bias_m``, ``bias_acc``: :func:`layout_offsets`;
    ``exact``: as in :func:`deflections`. Each row: the arithmetic of
    ``MeasurementModel.h_and_jacobian`` (with ``exact``: its bits).
    """
    N = X.shape[0]
    a, cc, e, g1, g2 = c[_A], c[_C], c[_E], c[_G1], c[_G2]
    trig = np.empty((N, 4))
    tau = np.empty((2, N))
    for i in range(N):               # eq. 11: arm torque
        q1, q2, dq1, dq2, a1, a2 = X[i, 0], X[i, 1], X[i, 2], X[i, 3], X[i, 4], X[i, 5]
        s2, c2 = math.sin(q2), math.cos(q2)
        b, bd = -e * s2, -e * c2
        phi = q1 + q2
        sp, cp = math.sin(phi), math.cos(phi)
        tau[0, i] = ((a + 2 * b) * a1 + (cc + b) * a2 + bd * (2 * dq1 * dq2 + dq2 * dq2)
                     - g1 * math.sin(q1) - g2 * cp)
        tau[1, i] = (cc + b) * a1 + cc * a2 - bd * dq1 * dq1 - g2 * cp
        trig[i, 0], trig[i, 1], trig[i, 2], trig[i, 3] = s2, c2, sp, cp
    for j in range(2):               # eq. 16: the spring's inverse
        deflections(tau[j], c[_K_HI + j], c[_K_SOFT + j], c[_DELTA + j], c[_TWO], exact, D0[:, j], D[:, j])
    jacobian = H.shape[1] > 0
    l1, v0, v1, Sv0, Sv1, g = c[_L1], c[_V0], c[_V1], c[_SV0], c[_SV1], c[_G]
    for i in range(N):               # eqs. 15-19 and 4c
        q1, q2, dq1, dq2, a1, a2 = X[i, 0], X[i, 1], X[i, 2], X[i, 3], X[i, 4], X[i, 5]
        s2, c2, sp, cp = trig[i, 0], trig[i, 1], trig[i, 2], trig[i, 3]
        y = Y[i]
        y[0] = c[_R0] * (q1 + D[i, 0])
        y[1] = c[_R1] * (q2 + D[i, 1])
        if bias_m >= 0:
            y[0] += X[i, bias_m]
            y[1] += X[i, bias_m + 1]
        dphi = dq1 + dq2
        u1, u2 = a1, -dq1 * dq1
        if m == 4:                   # eqs. 17-19: the accelerometer
            aphi = a1 + a2
            y[2] = l1 * (c2 * u1 - s2 * u2) + Sv0 * aphi - v0 * dphi * dphi - g * sp
            y[3] = l1 * (s2 * u1 + c2 * u2) + Sv1 * aphi - v1 * dphi * dphi + g * cp
            if bias_acc >= 0:
                y[2] += X[i, bias_acc]
                y[3] += X[i, bias_acc + 1]
        if not jacobian:
            continue
        Hi = H[i]
        # r (I + K(D)^-1 d tau_a / dx) for the motors (the scalar _arm_torque_jacobian) ...
        b, bd, bdd = -e * s2, -e * c2, e * s2
        gsp = g2 * sp
        for j in range(2):
            t = math.tanh(D[i, j] / c[_DELTA + j])
            k = c[_K_HI + j] - c[_K_SOFT + j] * (1.0 - (t ** c[_TWO] if exact else t * t))
            r = c[_R0 + j]
            rk = r / k
            if j == 0:
                Hi[0, 0] = rk * (-g1 * math.cos(q1) + gsp)
                Hi[0, 1] = rk * (2 * bd * a1 + bd * a2 + bdd * (2 * dq1 * dq2 + dq2 * dq2) + gsp)
                Hi[0, 2] = rk * (2 * bd * dq2)
                Hi[0, 3] = rk * (2 * bd * (dq1 + dq2))
                Hi[0, 4] = rk * (a + 2 * b)
                Hi[0, 5] = rk * (cc + b)
            else:
                Hi[1, 0] = rk * gsp
                Hi[1, 1] = rk * (bd * a1 - bdd * dq1 * dq1 + gsp)
                Hi[1, 2] = rk * (-2 * bd * dq1)
                Hi[1, 3] = rk * 0.0
                Hi[1, 4] = rk * (cc + b)
                Hi[1, 5] = rk * cc
            Hi[j, j] += r
        if bias_m >= 0:
            Hi[0, bias_m] = 1.0
            Hi[1, bias_m + 1] = 1.0
        if m == 4:                   # ... the specific force's (the scalar _specific_force_jacobian)
            dg0, dg1 = -g * cp, -g * sp
            Hi[2, 0], Hi[3, 0] = dg0, dg1
            Hi[2, 1] = dg0 + l1 * (-s2 * u1 - c2 * u2)
            Hi[3, 1] = dg1 + l1 * (c2 * u1 - s2 * u2)
            Hi[2, 2] = l1 * (s2 * 2 * dq1) - 2 * v0 * dphi
            Hi[3, 2] = l1 * (-c2 * 2 * dq1) - 2 * v1 * dphi
            Hi[2, 3] = -2 * v0 * dphi
            Hi[3, 3] = -2 * v1 * dphi
            Hi[2, 4] = l1 * c2 + Sv0
            Hi[3, 4] = l1 * s2 + Sv1
            Hi[2, 5], Hi[3, 5] = Sv0, Sv1
            if bias_acc >= 0:
                Hi[2, bias_acc] = 1.0
                Hi[3, bias_acc + 1] = 1.0


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
        self.constants = model_constants(meas)
        self.offsets = layout_offsets(meas.layout)

    def _evaluate(self, X: np.ndarray, jacobian: bool):
        X = np.ascontiguousarray(X, dtype=float)
        N, L = X.shape[0], self.layout
        Y, D = np.empty((N, L.m)), np.full((N, 2), np.nan)      # D: Newton starts cold
        H = np.zeros((N, L.m, L.n) if jacobian else (N, 0, 0))
        measure_many(X, self.constants, *self.offsets, True, D, Y, H, D)
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


__all__ = ["BatchedMeasurement", "measure_many", "deflections", "model_constants",
           "layout_offsets", "POW_EXPONENT"]
