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


# ---- eqs. 15-19: the measurement model ---------------------------------------------------------
class MeasurementModel:
    """``h(x)`` of eq. 15 and its analytic Jacobian, for the robot model ``p`` and the states and
    measurements of ``layout``.

    The inertia, Coriolis and gravity constants are the arm's
    (:class:`fmus.common.dynamics.ArmConstants`), so the filter's model is the plant's model with
    the filter's parameters.
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
        self._v, self._Sv, self._r = (tuple(map(float, a)) for a in (self.v, self.Sv, self.r))
        self._k_hi = tuple(map(float, p.k_hi))
        self._k_soft = tuple(float(h - lo) for h, lo in zip(p.k_hi, p.k_lo))
        self._delta = tuple(map(float, p.delta))

    # -- eq. 11: rigid arm torque and its derivatives
    def arm_torque(self, q, dq, ddq) -> np.ndarray:
        """``tau_a = M(q) ddq + C(q, dq) dq + G(q)`` (eq. 11, left side)."""
        return dynamics.inverse_dynamics_rigid(q, dq, ddq, self.p)

    def arm_torque_jacobian(self, q, dq, ddq) -> np.ndarray:
        """``d tau_a / d(q, dq, ddq)``, (2, 6), analytic."""
        return np.array(self._arm_torque_jacobian(float(q[0]), float(q[1]), float(dq[0]), float(dq[1]),
                                                  float(ddq[0]), float(ddq[1])))

    def _arm_torque_jacobian(self, q1, q2, dq1, dq2, a1, a2) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """:meth:`arm_torque_jacobian` on scalars, as two rows (the filter's hot path)."""
        s2, c2 = math.sin(q2), math.cos(q2)
        sp = math.sin(q1 + q2)
        b = -self.e * s2
        bd = -self.e * c2
        bdd = self.e * s2
        gsp = self.g2 * sp
        # d/dq1: gravity only (G1 = -g1 sin q1 - g2 cos phi, G2 = -g2 cos phi); d/dq2: M'(q2) ddq
        # + C' + G'; d/d dq: Coriolis; d/d ddq: M
        return ((-self.g1 * math.cos(q1) + gsp,
                 2 * bd * a1 + bd * a2 + bdd * (2 * dq1 * dq2 + dq2 * dq2) + gsp,
                 2 * bd * dq2, 2 * bd * (dq1 + dq2), self.a + 2 * b, self.c + b),
                (gsp, bd * a1 - bdd * dq1 * dq1 + gsp, -2 * bd * dq1, 0.0, self.c + b, self.c))

    # -- eq. 16: motor angles
    def motor_angles(self, x) -> np.ndarray:
        """``q_m = r (q_a + D(tau_a))`` (eq. 16 without the damping term), motor side."""
        D = dynamics.spring_deflection(self.arm_torque(x[Q_], x[DQ_], x[DDQ_]), self.p)
        return self.r * (np.asarray(x[Q_], float) + D)

    # -- eqs. 17-19: accelerometer
    def specific_force(self, x) -> np.ndarray:
        """Accelerometer reading (sensor x, z) of eqs. 17-19 in closed form (module docstring)."""
        q1, q2 = float(x[0]), float(x[1])
        dq1, dphi = float(x[2]), float(x[2]) + float(x[3])
        a1, aphi = float(x[4]), float(x[4]) + float(x[5])
        c2, s2 = math.cos(q2), math.sin(q2)
        phi = q1 + q2
        u1, u2 = a1, -dq1 * dq1                       # (ddq1, -dq1^2), rotated by R(-q2)
        fx = self.l1 * (c2 * u1 - s2 * u2) + self.Sv[0] * aphi - self.v[0] * dphi * dphi - self.g * math.sin(phi)
        fz = self.l1 * (s2 * u1 + c2 * u2) + self.Sv[1] * aphi - self.v[1] * dphi * dphi + self.g * math.cos(phi)
        return np.array([fx, fz])

    def specific_force_jacobian(self, x) -> np.ndarray:
        """``d f / d(q, dq, ddq)``, (2, 6), analytic."""
        return np.array(self._specific_force_jacobian(float(x[0]), float(x[1]), float(x[2]), float(x[3]),
                                                      float(x[4])))

    def _specific_force_jacobian(self, q1, q2, dq1, dq2, a1) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """:meth:`specific_force_jacobian` on scalars, as two rows (the filter's hot path)."""
        dphi = dq1 + dq2
        c2, s2 = math.cos(q2), math.sin(q2)
        phi = q1 + q2
        cp, sp = math.cos(phi), math.sin(phi)
        u1, u2 = a1, -dq1 * dq1
        l1, (v0, v1), (Sv0, Sv1), g = self.l1, self._v, self._Sv, self.g
        dg0, dg1 = -g * cp, -g * sp                     # d/dphi of g (-sin phi, cos phi)
        return ((dg0, dg0 + l1 * (-s2 * u1 - c2 * u2), l1 * (s2 * 2 * dq1) - 2 * v0 * dphi,
                 -2 * v0 * dphi, l1 * c2 + Sv0, Sv0),
                (dg1, dg1 + l1 * (c2 * u1 - s2 * u2), l1 * (-c2 * 2 * dq1) - 2 * v1 * dphi,
                 -2 * v1 * dphi, l1 * s2 + Sv1, Sv1))

    # -- eqs. 11 and 16 on scalars: the filter's hot path
    def _torque_deflection(self, x) -> tuple[tuple[float, float], tuple[float, float]]:
        """Arm torque ``tau_a`` (eq. 11) and the spring deflection ``D(tau_a)`` per joint, in
        scalar arithmetic (the same numbers as :meth:`arm_torque` and
        ``dynamics.spring_deflection``, without numpy's per-call overhead)."""
        q1, q2, dq1, dq2, a1, a2 = (float(v) for v in x[0:6])
        s2, c2 = math.sin(q2), math.cos(q2)
        b, bd = -self.e * s2, -self.e * c2
        cp = math.cos(q1 + q2)
        tau = ((self.a + 2 * b) * a1 + (self.c + b) * a2 + bd * (2 * dq1 * dq2 + dq2 * dq2)
               - self.g1 * math.sin(q1) - self.g2 * cp,
               (self.c + b) * a1 + self.c * a2 - bd * dq1 * dq1 - self.g2 * cp)
        D = []
        for i in range(2):
            k_hi, k_soft, delta, t = self._k_hi[i], self._k_soft[i], self._delta[i], tau[i]
            d = (t + math.copysign(k_soft * delta * math.tanh(abs(t) / (k_hi * delta)), t)) / k_hi
            for _ in range(50):
                f = k_hi * d - k_soft * delta * math.tanh(d / delta) - t
                d -= f / (k_hi - k_soft * (1.0 - math.tanh(d / delta) ** 2))   # sech^2, no overflow
                if abs(f) <= 1e-12 * max(1.0, abs(t)):
                    break
            D.append(d)
        return tau, (D[0], D[1])

    def h_and_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`h` and :meth:`jacobian` at ``x`` in one pass and in scalar arithmetic (one
        torque and one spring inversion instead of two, no numpy call per entry: the filter
        calls this once per update; the same numbers as :meth:`h` and :meth:`jacobian`)."""
        L = self.layout
        q1, q2, dq1, dq2, a1, a2 = (float(v) for v in x[0:6])
        _, D = self._torque_deflection(x)
        Jt = self._arm_torque_jacobian(q1, q2, dq1, dq2, a1, a2)
        H = np.zeros((L.m, L.n))
        y = np.empty(L.m)
        for i in range(2):
            k = self._k_hi[i] - self._k_soft[i] * (1.0 - math.tanh(D[i] / self._delta[i]) ** 2)
            r, rk = self._r[i], self._r[i] / k
            y[i] = r * ((q1, q2)[i] + D[i])
            H[i, 0:6] = [rk * j for j in Jt[i]]
            H[i, i] += r
        if L.bias_m is not None:
            y[0:2] += x[L.bias_m]
            H[0:2, L.bias_m] = np.eye(2)
        if L.use_accelerometer:
            y[2:4] = self.specific_force(x)
            H[2:4, 0:6] = self._specific_force_jacobian(q1, q2, dq1, dq2, a1)
            if L.bias_acc is not None:
                y[2:4] += x[L.bias_acc]
                H[2:4, L.bias_acc] = np.eye(2)
        return y, H

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


__all__ = ["EkfAccelerometerParameters", "Layout", "MeasurementModel", "continuous_model", "transition_matrices", "process_noise", "measurement_noise", "initial_covariance", "Q_JERK_DEFAULT", "Q_", "DQ_", "DDQ_"]
