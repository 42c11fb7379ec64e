"""The estimation model of Axelsson, Karlsson and Norrlöf (2012), shared by their EKF
(:mod:`fmus.estimators.ekf_accelerometer_model`), the particle filter
(:mod:`fmus.estimators.particle_filter_model`) and the Cramér-Rao bound
(:mod:`orchestration.crlb`): state layout, discrete-time model (eqs. 12-14), measurement
model with its analytic Jacobian (eqs. 15-19), noise (eq. 26), and the parameters of the
filters that run on it.

Estimation model (section 3.2)
------------------------------
State (eq. 12), arm side::

    x = (q_a[2], dq_a[2], ddq_a[2], b_m[2], b_acc[2])

``b_m`` (motor-angle bias, motor side, rad) and ``b_acc`` (accelerometer bias, sensor frame,
m/s2) are random walks used only with ``use_bias`` (the paper's simulation, section 4.3, does
not use them: "only the upper left corner of the matrices in (14) are used"). ``b_acc`` is
also dropped without the accelerometer (it would be unobservable). The first six states follow
a constant-acceleration model driven by the arm jerk reference ``u = dddq_a_ref`` and
discretised with zero-order hold (eqs. 13-14)::

    x_{t+1} = F x_t + G_u u_t + G_w w_t,
    F   = [[I, T I, T^2/2 I, 0, 0], [0, I, T I, 0, 0], [0, 0, I, 0, 0], [0, 0, 0, I, 0], [0, 0, 0, 0, I]]
    G_u = [T^3/6 I; T^2/2 I; T I; 0; 0]
    G_w = [[T^3/6 I, 0, 0], [T^2/2 I, 0, 0], [T I, 0, 0], [0, I, 0], [0, 0, I]]

with ``w = (w_jerk[2], w_bm[2], w_bacc[2])``, ``Cov(w) = diag(q_jerk I, q_bias_m I,
q_bias_acc I)`` (the jerk noise enters like the jerk input; the biases are random walks with
per-sample variances).

Measurements (section 3.3, eq. 15)
----------------------------------
* motor angles (eq. 16, damping neglected as in the paper): ``q_m = r (q_a + D) + b_m`` with
  the gearbox deflection ``D = tau_s^{-1}(tau_a)`` carrying the rigid arm torque
  ``tau_a = M(q_a) ddq_a + C(q_a, dq_a) dq_a + G(q_a)`` (eq. 11; the nonlinear spring of
  :mod:`fmus.common.dynamics` instead of the paper's linear ``k``);
* accelerometer (eqs. 17-19): the specific force at the sensor mount in the sensor frame
  (x along the forearm, z), ``f = R(phi)^T (p_ddot_s - g_vec) + b_acc`` (see
  :func:`fmus.common.kinematics.specific_force`). In link angles ``theta_1 = q_1``,
  ``phi = q_1 + q_2`` and with the mount vector ``v = (l2 + o_x, o_z)`` (tool frame) it is the
  closed form used here::

      f = l1 R(-q_2) (ddq_1, -dq_1^2) + S v dphi_dot - v dphi^2 + g (-sin phi, cos phi),
      S = [[0, 1], [-1, 0]]

  whose Jacobian is analytic (:func:`measurement_jacobian`).

Noise (eq. 26)
--------------
The paper's ``Q = 4e-6 I``, ``R = diag(1e-6 I, 1e-4 I)``. The paper's robot model (its eq. 10
writes ``r_g q_m - q_a``, so ``r_g`` is arm/motor and eq. 16 gives ``q_m`` on the motor side)
measures the motor angles motor side; so ``R_motor = 1e-6 rad^2`` motor side (1 mrad, about
5 urad arm side with our gear ratios) and ``R_acc = 1e-4 (m/s^2)^2`` (0.01 m/s^2) are taken as
SI values unchanged. ``Q`` is the jerk-noise variance, a design parameter (the paper:
"considered as a filter design parameter"); its default here is tuned for our plant, whose
lightly damped 8-15 Hz gearbox modes make the true arm jerk deviate from the reference by tens
of rad/s^3 (see :data:`Q_JERK_DEFAULT`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fmus.common import dynamics
from fmus.common.jit import kernel
from fmus.common.parameters import ParameterError, param
from fmus.common.robot_params import RobotAtInitialPose, RobotParameters

PAPER = "Axelsson, Karlsson, Norrlöf 2012"

#: Default jerk-noise variance [(rad/s3)^2 per sample]. The paper's 4e-6 (eq. 26) is for its
#: smooth simulation model; with it, on our plant (lightly damped 8-15 Hz gearbox modes, arm
#: accelerations off the reference by up to about 1 rad/s^2) the filter trusts the jerk
#: reference and the accelerometer makes no difference. A sweep at 100 Hz on the corner path of
#: the tests (4e-6 ... 1e4) puts the motor-only filter's best angle RMSE at about 10, where the
#: filter with the accelerometer is within 5 % of its own best.
Q_JERK_DEFAULT = 10.0


@dataclass(frozen=True)
class EkfAccelerometerParameters(RobotAtInitialPose):
    """Parameters of the EKF: its robot model (inherited; differing from the plant's values is
    a model error), initial estimate, noise covariances and switches."""

    use_accelerometer: bool = param(True, "1", "fuse the accelerometer (eqs. 17-19); off: motor angles only")
    use_bias: bool = param(False, "1", "bias states for the motor angles and the accelerometer "
                           "(eq. 12); off as in the paper's simulation (section 4.3)")
    q_jerk: float = param(Q_JERK_DEFAULT, "(rad/s3)2", "process noise variance of the arm jerk "
                          "(per joint, per sample)", low=0.0, low_inclusive=False,
                          source=f"{PAPER}, eq. 26 has 4e-6 for its model; tuned for this plant")
    q_bias_m: float = param(1e-10, "rad2", "random-walk variance per sample of the motor-angle bias",
                            low=0.0, low_inclusive=False)
    q_bias_acc: float = param(1e-8, "(m/s2)2", "random-walk variance per sample of the accelerometer bias",
                              low=0.0, low_inclusive=False)
    r_motor: float = param(1e-6, "rad2", "measurement noise variance of the motor angles (motor side)",
                           low=0.0, low_inclusive=False, source=f"{PAPER}, eq. 26")
    r_acc: float = param(1e-4, "(m/s2)2", "measurement noise variance of the accelerometer",
                         low=0.0, low_inclusive=False, source=f"{PAPER}, eq. 26")
    p0_q: float = param(1e-3, "rad", "initial standard deviation of the arm angles", low=0.0,
                        low_inclusive=False)
    p0_dq: float = param(1e-2, "rad/s", "initial standard deviation of the arm angular velocities",
                         low=0.0, low_inclusive=False)
    p0_ddq: float = param(1e-1, "rad/s2", "initial standard deviation of the arm angular accelerations",
                          low=0.0, low_inclusive=False)
    p0_bias_m: float = param(1e-3, "rad", "initial standard deviation of the motor-angle bias",
                             low=0.0, low_inclusive=False)
    p0_bias_acc: float = param(0.1, "m/s2", "initial standard deviation of the accelerometer bias",
                               low=0.0, low_inclusive=False)
    index_x: int = param(1, "1", "index (1-based) of the sensor-frame x component in acc_s", low=1, high=3)
    index_z: int = param(3, "1", "index (1-based) of the sensor-frame z component in acc_s", low=1, high=3)

    def check(self) -> None:
        """The robot's rules, ``index_x`` differs from ``index_z`` and the initial pose exists;
        raises :class:`ParameterError`."""
        super().check()
        if self.index_x == self.index_z:
            raise ParameterError(f"parameters 'index_x' and 'index_z' must differ (both {self.index_x})")
        self.initial_angles()


# ---- state layout ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Layout:
    """Which states and measurements the filter has (indices into ``x`` and ``y``)."""

    use_accelerometer: bool
    use_bias: bool

    @property
    def n(self) -> int:
        """Number of states: 6, plus 2 motor biases, plus 2 accelerometer biases."""
        return 6 + (2 if self.use_bias else 0) + (2 if self.use_bias and self.use_accelerometer else 0)

    @property
    def m(self) -> int:
        """Number of measurements: 2 motor angles (+ 2 accelerometer components)."""
        return 4 if self.use_accelerometer else 2

    @property
    def bias_m(self) -> slice | None:
        """Indices of the motor-angle biases in ``x`` (None without ``use_bias``)."""
        return slice(6, 8) if self.use_bias else None

    @property
    def bias_acc(self) -> slice | None:
        """Indices of the accelerometer biases in ``x`` (None without both switches)."""
        return slice(8, 10) if self.use_bias and self.use_accelerometer else None

    def measurement_vector(self, q_m, acc_xz=None) -> np.ndarray:
        """Stack the readings as ``y`` of eq. 15 (the accelerometer only if it is used).

        Parameters
        ----------
        q_m
            Measured motor angles (2,) [rad], motor side (eq. 16).
        acc_xz
            Accelerometer specific force (sensor x, z) (2,) [m/s^2] (eqs. 17-19); ignored, and
            may be None, when the layout does not use the accelerometer.
        """
        y = np.asarray(q_m, float)
        if self.use_accelerometer:
            y = np.concatenate([y, np.asarray(acc_xz, float)])
        return y


Q_, DQ_, DDQ_ = slice(0, 2), slice(2, 4), slice(4, 6)


# ---- eqs. 13-14: the discrete-time model ------------------------------------------------------
def continuous_model(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the continuous constant-acceleration model ``x_dot = A x + B u`` (jerk input),
    whose zero-order hold is eq. 13a, with the states of ``layout`` (the biases: zero rows)."""
    n = layout.n
    A = np.zeros((n, n))
    A[0:2, 2:4] = np.eye(2)
    A[2:4, 4:6] = np.eye(2)
    B = np.zeros((n, 2))
    B[4:6] = np.eye(2)
    return A, B


def transition_matrices(T: float, layout: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``F``, ``G_u``, ``G_w`` of eqs. 13a-14 for the sample period ``T`` [s] (the zero-order
    hold of :func:`continuous_model`), with the states of ``layout``."""
    n = layout.n
    I2 = np.eye(2)
    F = np.eye(n)
    F[0:2, 2:4] = T * I2
    F[0:2, 4:6] = T * T / 2 * I2
    F[2:4, 4:6] = T * I2
    Gu = np.zeros((n, 2))
    Gu[0:2] = T ** 3 / 6 * I2
    Gu[2:4] = T * T / 2 * I2
    Gu[4:6] = T * I2
    nw = 2 + (n - 6)
    Gw = np.zeros((n, nw))
    Gw[:, 0:2] = Gu
    if n > 6:
        Gw[6:, 2:] = np.eye(n - 6)
    return F, Gu, Gw


def process_noise(p: EkfAccelerometerParameters, layout: Layout) -> np.ndarray:
    """``Cov(w)`` (eq. 26's ``Q``) from the parameters ``p``: jerk noise, then the bias random
    walks of ``layout``."""
    q = [p.q_jerk] * 2
    if layout.use_bias:
        q += [p.q_bias_m] * 2
        if layout.use_accelerometer:
            q += [p.q_bias_acc] * 2
    return np.diag(q)


def measurement_noise(p: EkfAccelerometerParameters, layout: Layout) -> np.ndarray:
    """``R`` of eq. 26 from the parameters ``p``: motor angles, then the accelerometer (if
    ``layout`` fuses it)."""
    return np.diag([p.r_motor] * 2 + ([p.r_acc] * 2 if layout.use_accelerometer else []))


def initial_covariance(p: EkfAccelerometerParameters, layout: Layout) -> np.ndarray:
    """``P_0`` from the initial standard deviations of ``p``, for the states of ``layout``."""
    s = [p.p0_q] * 2 + [p.p0_dq] * 2 + [p.p0_ddq] * 2
    if layout.use_bias:
        s += [p.p0_bias_m] * 2
        if layout.use_accelerometer:
            s += [p.p0_bias_acc] * 2
    return np.diag(np.square(s))


# ---- eqs. 11 and 15-19 on scalars: compiled kernels (the filters' hot path) -------------------
# The model is written once, here, per state (the EKF: measurement_kernel); the particle filter
# and the Cramer-Rao bound run it over many states with
# fmus.estimators.axelsson2012_batched.measure_many, which calls these kernels row by row. The
# pieces are inline="always": numba compiles them into their caller (one loop body, each sine
# and cosine computed once, the layout switches constant where the caller makes them so).

#: Order of the constants array of the kernels (:attr:`MeasurementModel.constants`).
K_A, K_C, K_E, K_G1, K_G2, K_G, K_L1, K_V0, K_V1, K_KHI, K_KSOFT, K_DELTA, K_R = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 13, 15)

#: ``max |d^2/dx^2 tanh(x)| / 2 = 2 / (3 sqrt(3))``: bounds Newton's next residual
#: (:func:`spring_deflection_kernel`).
_HALF_MAX_TANH2 = 2.0 / (3.0 * math.sqrt(3.0))


@kernel(inline="always")
def motion(x: np.ndarray) -> tuple:
    """The motion part of the state ``x`` as the kernels below take it, 11 floats:
    ``(q_1, q_2, dq_1, dq_2, ddq_1, ddq_2, sin q_1, sin q_2, cos q_2, sin phi, cos phi)``
    (``phi = q_1 + q_2``): the sines and cosines ``h`` needs, computed once per state for ``h``
    and ``H`` (and stored with it over many states,
    :func:`fmus.estimators.axelsson2012_batched.measure_many`)."""
    q1, q2 = x[0], x[1]
    phi = q1 + q2
    return q1, q2, x[2], x[3], x[4], x[5], math.sin(q1), math.sin(q2), math.cos(q2), math.sin(phi), math.cos(phi)


@kernel(inline="always")
def arm_torque_kernel(s: tuple, k: np.ndarray) -> tuple:
    """The rigid arm torque ``tau_a = M(q) ddq + C(q, dq) dq + G(q)`` (eq. 11) at the motion
    ``s`` (:func:`motion`), as two floats; ``k`` the model's constants
    (:attr:`MeasurementModel.constants`)."""
    q1, q2, dq1, dq2, a1, a2, s1, s2, c2, sp, cp = s
    a, c, e, g1, g2 = k[K_A], k[K_C], k[K_E], k[K_G1], k[K_G2]
    b, bd = -e * s2, -e * c2
    tau0 = (a + 2 * b) * a1 + (c + b) * a2 + bd * (2 * dq1 * dq2 + dq2 * dq2) - g1 * s1 - g2 * cp
    tau1 = (c + b) * a1 + c * a2 - bd * dq1 * dq1 - g2 * cp
    return tau0, tau1


@kernel(inline="always")
def arm_torque_jacobian_into(s: tuple, k: np.ndarray, w0: float, w1: float, J: np.ndarray) -> None:
    """``d tau_a / d(q, dq, ddq)`` of eq. 11 at the motion ``s`` (:func:`motion`), analytic,
    its rows times ``w0`` and ``w1`` (the motor angles' ``r / K(D)``, :func:`jacobian_into`;
    1 for the Jacobian itself), into ``J[0:2, 0:6]``; ``k`` the model's constants
    (:attr:`MeasurementModel.constants`)."""
    q1, q2, dq1, dq2, a1, a2, s1, s2, c2, sp, cp = s
    e, g2 = k[K_E], k[K_G2]
    b = -e * s2
    bd = -e * c2
    bdd = e * s2
    gsp = g2 * sp
    # d/dq1: gravity only (G1 = -g1 sin q1 - g2 cos phi, G2 = -g2 cos phi); d/dq2: M'(q2) ddq
    # + C' + G'; d/d dq: Coriolis; d/d ddq: M
    J[0, 0] = w0 * (-k[K_G1] * math.cos(q1) + gsp)
    J[0, 1] = w0 * (2 * bd * a1 + bd * a2 + bdd * (2 * dq1 * dq2 + dq2 * dq2) + gsp)
    J[0, 2] = w0 * (2 * bd * dq2)
    J[0, 3] = w0 * (2 * bd * (dq1 + dq2))
    J[0, 4] = w0 * (k[K_A] + 2 * b)
    J[0, 5] = w0 * (k[K_C] + b)
    J[1, 0] = w1 * gsp
    J[1, 1] = w1 * (bd * a1 - bdd * dq1 * dq1 + gsp)
    J[1, 2] = w1 * (-2 * bd * dq1)
    J[1, 3] = w1 * 0.0
    J[1, 4] = w1 * (k[K_C] + b)
    J[1, 5] = w1 * k[K_C]


@kernel(aot="float64[:, :](float64[:], float64[:])")
def arm_torque_jacobian_kernel(x: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``d tau_a / d(q, dq, ddq)`` (2, 6) of eq. 11 at the state ``x``
    (:func:`arm_torque_jacobian_into`); ``k`` the model's constants."""
    J = np.empty((2, 6))
    arm_torque_jacobian_into(motion(x), k, 1.0, 1.0, J)
    return J


@kernel(inline="always")
def specific_force_into(s: tuple, k: np.ndarray, f: np.ndarray, row: int) -> None:
    """The accelerometer reading (sensor x, z) of eqs. 17-19 in closed form (module docstring)
    at the motion ``s`` (:func:`motion`) into ``f[row:row + 2]``; ``k`` the model's constants."""
    q1, q2, dq1, dq2, a1, a2, s1, s2, c2, sp, cp = s
    dphi, aphi = dq1 + dq2, a1 + a2
    l1, v0, v1, g = k[K_L1], k[K_V0], k[K_V1], k[K_G]
    Sv0, Sv1 = v1, -v0                              # S v, S = [[0, 1], [-1, 0]]
    u1, u2 = a1, -dq1 * dq1                         # (ddq1, -dq1^2), rotated by R(-q2)
    f[row] = l1 * (c2 * u1 - s2 * u2) + Sv0 * aphi - v0 * dphi * dphi - g * sp
    f[row + 1] = l1 * (s2 * u1 + c2 * u2) + Sv1 * aphi - v1 * dphi * dphi + g * cp


@kernel(inline="always")
def specific_force_jacobian_into(s: tuple, k: np.ndarray, J: np.ndarray, row: int) -> None:
    """``d f / d(q, dq, ddq)`` of the accelerometer reading (:func:`specific_force_into`) at the
    motion ``s`` (:func:`motion`), analytic, into ``J[row:row + 2, 0:6]``; ``k`` the model's
    constants."""
    q1, q2, dq1, dq2, a1, a2, s1, s2, c2, sp, cp = s
    dphi = dq1 + dq2
    l1, v0, v1, g = k[K_L1], k[K_V0], k[K_V1], k[K_G]
    Sv0, Sv1 = v1, -v0
    u1, u2 = a1, -dq1 * dq1
    x_, z_ = row, row + 1
    dg0, dg1 = -g * cp, -g * sp                     # d/dphi of g (-sin phi, cos phi)
    J[x_, 0], J[z_, 0] = dg0, dg1
    J[x_, 1] = dg0 + l1 * (-s2 * u1 - c2 * u2)
    J[z_, 1] = dg1 + l1 * (c2 * u1 - s2 * u2)
    J[x_, 2] = l1 * (s2 * 2 * dq1) - 2 * v0 * dphi
    J[z_, 2] = l1 * (-c2 * 2 * dq1) - 2 * v1 * dphi
    J[x_, 3] = -2 * v0 * dphi
    J[z_, 3] = -2 * v1 * dphi
    J[x_, 4] = l1 * c2 + Sv0
    J[z_, 4] = l1 * s2 + Sv1
    J[x_, 5], J[z_, 5] = Sv0, Sv1


@kernel(aot="Tuple((float64[:], float64[:, :]))(float64[:], float64[:])")
def specific_force_kernel(x: np.ndarray, k: np.ndarray) -> tuple:
    """The accelerometer reading (sensor x, z) of eqs. 17-19 and its Jacobian
    ``d f / d(q, dq, ddq)`` (2, 6) at the state ``x`` (:func:`specific_force_into`,
    :func:`specific_force_jacobian_into`); ``k`` the model's constants."""
    f, J = np.empty(2), np.empty((2, 6))
    specific_force_into(motion(x), k, f, 0)
    specific_force_jacobian_into(motion(x), k, J, 0)
    return f, J


#: Newton's method on the gearbox spring (:func:`spring_deflection_kernel`): at most this many
#: steps, to the residual ``|tau_s(D) - tau| <= NEWTON_RTOL max(1, |tau|)``.
NEWTON_STEPS, NEWTON_RTOL = 50, 1e-12


@kernel(inline="always")
def spring_start(tau: float, k_hi: float, k_soft: float, delta: float, start: float) -> float:
    """Where Newton's method on the spring (:func:`spring_deflection_kernel`, with its
    ``k_hi``, ``k_soft`` and ``delta``) starts for the torque ``tau``: ``start``, or if it is
    NaN the high-stiffness asymptote shifted by the soft zone."""
    if math.isnan(start):
        return (tau + math.copysign(k_soft * delta * math.tanh(abs(tau) / (k_hi * delta)), tau)) / k_hi
    return start


@kernel(inline="always")
def spring_newton_step(d: float, tau: float, k_hi: float, k_soft: float, delta: float, bound_stop: bool) -> tuple:
    """One step of Newton's method on ``tau_s(d) = tau`` (:func:`spring_deflection_kernel`, with
    its ``k_hi``, ``k_soft`` and ``delta``): ``(d_next, done)``, done when the residual at ``d``
    is within the tolerance or, with ``bound_stop``, Newton's bound on the residual at
    ``d_next`` is."""
    tol = NEWTON_RTOL * max(1.0, abs(tau))
    th = math.tanh(d / delta)
    f = k_hi * d - k_soft * delta * th - tau
    slope = k_hi - k_soft * (1.0 - th * th)                 # sech^2, no overflow
    d -= f / slope
    if abs(f) <= tol:
        return d, True
    # |tau_s(d_next) - tau| <= max|tau_s''| / 2 (f / k)^2, tau_s'' = -(k_soft / delta) tanh''
    return d, bound_stop and _HALF_MAX_TANH2 * k_soft / delta * (f / slope) * (f / slope) <= tol


@kernel(inline="always")
def spring_deflection_kernel(tau: float, k_hi: float, k_soft: float, delta: float, start: float,
                             bound_stop: bool) -> float:
    """The gearbox deflection ``D`` of one joint carrying the torque ``tau`` (eq. 16's spring,
    that of :mod:`fmus.common.dynamics`: ``tau_s = k_hi D - k_soft delta tanh(D / delta)``,
    ``k_soft = k_hi - k_lo``).

    Newton's method, as ``dynamics.spring_deflection``, from ``start`` (NaN: from the
    high-stiffness asymptote shifted by the soft zone, :func:`spring_start`), at most
    :data:`NEWTON_STEPS` steps (:func:`spring_newton_step`): step, then stop once the residual
    before the step, ``|tau_s(D) - tau|``, is within ``NEWTON_RTOL max(1, |tau|)``. With
    ``bound_stop`` (the particle filter: warm starts, fewer ``tanh``) it also stops as soon as
    Newton's bound on the next residual, ``max|tau_s''| / 2 (f / k)^2`` with
    ``max|tau_s''| = 4 / (3 sqrt 3) k_soft / delta``, is within the tolerance: the same root
    within the same tolerance, one step earlier.
    """
    d = spring_start(tau, k_hi, k_soft, delta, start)
    for _ in range(NEWTON_STEPS):
        d, done = spring_newton_step(d, tau, k_hi, k_soft, delta, bound_stop)
        if done:
            break
    return d


@kernel(inline="always")
def spring_stiffness_kernel(d: float, k_hi: float, k_soft: float, delta: float) -> float:
    """``d tau_s / dD = k_hi - k_soft (1 - tanh^2(D / delta))`` of the spring of
    :func:`spring_deflection_kernel` at the deflection ``d``."""
    th = math.tanh(d / delta)
    return k_hi - k_soft * (1.0 - th * th)


@kernel(inline="always")
def deflections_kernel(s: tuple, k: np.ndarray, start0: float, start1: float, bound_stop: bool) -> tuple:
    """The gearbox deflections ``D = tau_s^-1(tau_a)`` (two floats) carrying the arm torque of
    eq. 11 at the motion ``s`` (:func:`motion`), by :func:`spring_deflection_kernel` from
    ``start0``, ``start1`` (NaN: cold) with ``bound_stop``; ``k`` the model's constants."""
    tau0, tau1 = arm_torque_kernel(s, k)
    return (spring_deflection_kernel(tau0, k[K_KHI], k[K_KSOFT], k[K_DELTA], start0, bound_stop),
            spring_deflection_kernel(tau1, k[K_KHI + 1], k[K_KSOFT + 1], k[K_DELTA + 1], start1, bound_stop))


@kernel(inline="always")
def h_into(x: np.ndarray, s: tuple, k: np.ndarray, use_accelerometer: bool, use_bias: bool, d0: float, d1: float,
           y: np.ndarray) -> None:
    """``h(x)`` of eq. 15 into ``y`` (m,) for the layout of the two switches
    ``use_accelerometer`` and ``use_bias`` (:class:`Layout`), given ``s`` the motion of ``x``
    (:func:`motion`) and its gearbox deflections ``d0``, ``d1`` (:func:`deflections_kernel`);
    ``k`` the constants (:attr:`MeasurementModel.constants`): motor angles
    ``r (q_a + D) + b_m`` (eq. 16), the accelerometer (:func:`specific_force_into`) ``+ b_acc``."""
    y[0] = k[K_R] * (s[0] + d0)
    y[1] = k[K_R + 1] * (s[1] + d1)
    if use_bias:
        y[0] += x[6]
        y[1] += x[7]
    if use_accelerometer:
        specific_force_into(s, k, y, 2)
        if use_bias:
            y[2] += x[8]
            y[3] += x[9]


@kernel(inline="always")
def jacobian_into(s: tuple, k: np.ndarray, use_accelerometer: bool, use_bias: bool, d0: float, d1: float,
                  H: np.ndarray) -> None:
    """``H = dh/dx`` (eq. 4c) of :func:`h_into` at a state of motion ``s`` (:func:`motion`; the
    Jacobian does not depend on the biases) with the gearbox deflections
    ``d0``, ``d1`` (:func:`deflections_kernel`) into ``H`` (m, n) (the entries not written
    here are the caller's zeros), for the layout of the switches ``use_accelerometer`` and
    ``use_bias`` and the constants ``k`` (as :func:`h_into`): ``r (I + K(D)^-1 d tau_a / dx)``
    for the motor angles (``K(D)`` the spring stiffness, :func:`spring_stiffness_kernel`), the
    accelerometer's (:func:`specific_force_jacobian_into`), identities for the biases."""
    r0, r1 = k[K_R], k[K_R + 1]
    rk0 = r0 / spring_stiffness_kernel(d0, k[K_KHI], k[K_KSOFT], k[K_DELTA])
    rk1 = r1 / spring_stiffness_kernel(d1, k[K_KHI + 1], k[K_KSOFT + 1], k[K_DELTA + 1])
    arm_torque_jacobian_into(s, k, rk0, rk1, H)
    H[0, 0] += r0
    H[1, 1] += r1
    if use_bias:
        H[0, 6] = 1.0
        H[1, 7] = 1.0
    if use_accelerometer:
        specific_force_jacobian_into(s, k, H, 2)
        if use_bias:
            H[2, 8] = 1.0
            H[3, 9] = 1.0


@kernel(aot="Tuple((float64[:], float64[:, :]))(float64[:], float64[:], boolean, boolean)")
def measurement_kernel(x: np.ndarray, k: np.ndarray, use_accelerometer: bool, use_bias: bool) -> tuple:
    """``h(x)`` of eq. 15 and its Jacobian ``H`` (eq. 4c) for the layout of the two switches
    ``use_accelerometer`` and ``use_bias`` (:class:`Layout`), ``k`` the constants
    (:attr:`MeasurementModel.constants`): :func:`deflections_kernel` from the cold start,
    :func:`h_into` and :func:`jacobian_into`."""
    m = 4 if use_accelerometer else 2
    n = 6 + (2 if use_bias else 0) + (2 if use_bias and use_accelerometer else 0)
    y, H = np.empty(m), np.zeros((m, n))
    s = motion(x)                    # one sine and cosine per angle for h and H
    d0, d1 = deflections_kernel(s, k, math.nan, math.nan, False)
    h_into(x, s, k, use_accelerometer, use_bias, d0, d1, y)
    jacobian_into(s, k, use_accelerometer, use_bias, d0, d1, H)
    return y, H


# ---- eqs. 15-19: the measurement model ---------------------------------------------------------
class MeasurementModel:
    """``h(x)`` of eq. 15 and its analytic Jacobian, for the robot model ``p`` and the states and
    measurements of ``layout``.

    The inertia, Coriolis and gravity constants are the arm's
    (:class:`fmus.common.dynamics.ArmConstants`), so the filter's model is the plant's model with
    the filter's parameters. :meth:`h_and_jacobian` (the filters' hot path) and the scalar
    Jacobians are compiled kernels; :meth:`h` and :meth:`jacobian` compute the same through
    :mod:`fmus.common.dynamics` (a check of the kernels, and the readable form).
    """

    def __init__(self, p: RobotParameters, layout: Layout) -> None:
        self.p = p
        self.layout = layout
        k = dynamics.arm_constants(p)
        self.a, self.c, self.g2 = k.a, k.c, k.g2
        # e and g1 rounded as when they were read back from M(q) at q2 = pi/2 and G(q) at
        # q = (pi/2, -pi/2): the filters' results keep their bits (k.g1 differs in the last one)
        self.e = k.c - (k.c - k.e)
        self.g1 = (k.g1 + k.g2) - k.g2
        self.g = float(p.g)
        self.l1 = float(p.l1)
        self.v = np.array([p.l2 + p.sensor_offset[0], p.sensor_offset[1]], float)   # mount, tool frame
        self.Sv = np.array([self.v[1], -self.v[0]])
        self.r = np.asarray(p.gear_ratio, float)
        k_soft = [h - lo for h, lo in zip(p.k_hi, p.k_lo)]
        #: The kernels' constants (the one vector of the model, single or over many states), in
        #: the order of the ``K_*`` indices.
        self.constants = np.array([self.a, self.c, self.e, self.g1, self.g2, self.g, self.l1, *self.v,
                                   *p.k_hi, *k_soft, *p.delta, *self.r], float)
        #: The kernels' layout switches ``(use_accelerometer, use_bias)``.
        self.switches = (bool(layout.use_accelerometer), bool(layout.use_bias))

    # -- eq. 11: rigid arm torque and its derivatives
    def arm_torque(self, q, dq, ddq) -> np.ndarray:
        """``tau_a = M(q) ddq + C(q, dq) dq + G(q)`` (eq. 11, left side)."""
        return dynamics.inverse_dynamics_rigid(q, dq, ddq, self.p)

    def arm_torque_jacobian(self, q, dq, ddq) -> np.ndarray:
        """``d tau_a / d(q, dq, ddq)``, (2, 6), analytic (:func:`arm_torque_jacobian_kernel`)."""
        return arm_torque_jacobian_kernel(np.concatenate([q, dq, ddq]).astype(float), self.constants)

    # -- eq. 16: motor angles
    def motor_angles(self, x) -> np.ndarray:
        """``q_m = r (q_a + D(tau_a))`` (eq. 16 without the damping term), motor side."""
        D = dynamics.spring_deflection(self.arm_torque(x[Q_], x[DQ_], x[DDQ_]), self.p)
        return self.r * (np.asarray(x[Q_], float) + D)

    # -- eqs. 17-19: accelerometer
    def specific_force(self, x) -> np.ndarray:
        """Accelerometer reading (sensor x, z) of eqs. 17-19 in closed form (module docstring)."""
        return specific_force_kernel(np.asarray(x, float)[0:6], self.constants)[0]

    def specific_force_jacobian(self, x) -> np.ndarray:
        """``d f / d(q, dq, ddq)``, (2, 6), analytic."""
        return specific_force_kernel(np.asarray(x, float)[0:6], self.constants)[1]

    def h_and_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`h` and :meth:`jacobian` at ``x`` in one compiled pass
        (:func:`measurement_kernel`: one torque and one spring inversion instead of two; the
        same numbers as :meth:`h` and :meth:`jacobian` to round-off)."""
        return measurement_kernel(np.asarray(x, float), self.constants, *self.switches)

    # -- eq. 15
    def h(self, x) -> np.ndarray:
        """The noise-free measurement ``h(x)`` of eq. 15: motor angles (+ accelerometer x, z)."""
        L = self.layout
        y = self.motor_angles(x)
        if L.bias_m is not None:
            y = y + x[L.bias_m]
        if L.use_accelerometer:
            f = self.specific_force(x)
            if L.bias_acc is not None:
                f = f + x[L.bias_acc]
            y = np.concatenate([y, f])
        return y

    def jacobian(self, x) -> np.ndarray:
        """``H = dh/dx`` (eq. 4c), analytic: ``r (I + K(D)^-1 d tau_a/dx)`` for the motors
        (``K(D)`` the spring stiffness at the deflection), :meth:`specific_force_jacobian` for
        the accelerometer, identities for the biases."""
        L = self.layout
        H = np.zeros((L.m, L.n))
        tau = self.arm_torque(x[Q_], x[DQ_], x[DDQ_])
        D = dynamics.spring_deflection(tau, self.p)
        k = dynamics.spring_stiffness(D, self.p)
        Jt = self.arm_torque_jacobian(x[Q_], x[DQ_], x[DDQ_])
        H[0:2, 0:6] = (self.r / k)[:, None] * Jt
        H[0:2, 0:2] += np.diag(self.r)
        if L.bias_m is not None:
            H[0:2, L.bias_m] = np.eye(2)
        if L.use_accelerometer:
            H[2:4, 0:6] = self.specific_force_jacobian(x)
            if L.bias_acc is not None:
                H[2:4, L.bias_acc] = np.eye(2)
        return H


__all__ = ["EkfAccelerometerParameters", "Layout", "MeasurementModel", "continuous_model", "transition_matrices", "process_noise", "measurement_noise", "initial_covariance", "Q_JERK_DEFAULT", "Q_", "DQ_", "DDQ_",
           "K_A", "K_C", "K_E", "K_G1", "K_G2", "K_G", "K_L1", "K_V0", "K_V1", "K_KHI", "K_KSOFT", "K_DELTA", "K_R",
           "motion", "arm_torque_kernel", "arm_torque_jacobian_into", "arm_torque_jacobian_kernel",
           "specific_force_into", "specific_force_jacobian_into", "specific_force_kernel", "NEWTON_STEPS",
           "NEWTON_RTOL", "spring_start", "spring_newton_step", "spring_deflection_kernel", "spring_stiffness_kernel",
           "deflections_kernel", "h_into", "jacobian_into", "measurement_kernel"]
